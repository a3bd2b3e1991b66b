"""`kitbench eval`: statistics, suites, failure categories, reports, determinism across workers, bad input."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import gymnasium as gym
import pytest

import kitbench
from kitbench.envs.grasp import GraspHistory
from kitbench.evaluation.config import EvalConfig
from kitbench.evaluation.episode import EpisodeResult
from kitbench.evaluation.outcomes import failure_category
from kitbench.evaluation.plots import error_bars
from kitbench.evaluation.report import without_timing
from kitbench.evaluation.runner import pick_video_seeds, run_eval
from kitbench.evaluation.stats import describe, rate, wilson_interval
from kitbench.evaluation.suite import Suite, adhoc_suite, load_suite
from kitbench.tasks.lift_peg_upright import MAX_TILT
from tests import launch

ROOT = Path(__file__).resolve().parents[1]
SUITES = sorted((ROOT / "eval" / "suites").glob("*.toml"))


# -- statistics ------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "k,n,lo,hi", [(0, 10, 0.0, 0.2775), (10, 10, 0.7225, 1.0), (5, 10, 0.2366, 0.7634), (95, 100, 0.8882, 0.9785)]
)
def test_wilson_interval_matches_published_values(k, n, lo, hi):
    a, b = wilson_interval(k, n)
    assert a == pytest.approx(lo, abs=1e-4) and b == pytest.approx(hi, abs=1e-4)


@pytest.mark.parametrize("n", [1, 7, 10, 50, 100, 200, 1000])
def test_wilson_interval_ends_are_exact_at_none_and_all(n):
    """0/N starts at exactly 0 and N/N ends at exactly 1: a bound a rounding error past the rate (0/200 gave
    1.7e-18) makes a negative error bar, which matplotlib refuses to draw."""
    assert wilson_interval(0, n)[0] == 0.0 and wilson_interval(n, n)[1] == 1.0
    assert 0.0 < wilson_interval(0, n)[1] and wilson_interval(n, n)[0] < 1.0


def test_error_bars_are_never_negative_and_measure_from_the_rate():
    """A results file written before the ends were exact holds 0/200 as [1.7e-18, 0.0188]: its bar below is 0,
    not -1.7e-18 (which matplotlib refuses); other bars are the interval's distances from the rate."""
    old = {"rate": 0.0, "ci95": [1.734723475976807e-18, 0.018845326377266575]}
    below, above = error_bars([old, rate(8, 200)])
    assert below[0] == 0.0 and above[0] == pytest.approx(0.018845326377266575)
    lo, hi = wilson_interval(8, 200)
    assert below[1] == pytest.approx(0.04 - lo) and above[1] == pytest.approx(hi - 0.04)


def test_describe_quantiles_and_empty():
    d = describe(range(1, 11))
    assert d["n"] == 10 and d["mean"] == 5.5 and d["median"] == 5.5 and d["min"] == 1 and d["max"] == 10
    assert describe([]) is None


# -- suites ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("path", SUITES, ids=[p.stem for p in SUITES])
def test_committed_suites_load_and_avoid_recording_seeds(path):
    suite = load_suite(path)
    assert min(suite.seeds) >= 1_000_000  # recordings start at seed 0
    assert suite.name == path.stem


def test_validation_suites_share_no_seed_with_any_other_suite():
    """Each task has a `*_val` suite to choose on, disjoint from every suite figures are scored on."""
    val = [p for p in SUITES if p.stem.endswith("_val")]
    assert {load_suite(p).task for p in val} == set(kitbench.TASKS)
    scored = set().union(*(load_suite(p).seeds for p in SUITES if p not in val))
    for path in val:
        assert not set(load_suite(path).seeds) & scored, path.stem


def test_one_committed_suite_per_task():
    assert {load_suite(p).task for p in SUITES} == set(kitbench.TASKS)


@pytest.mark.parametrize(
    "body,message",
    [
        (
            'task = "Nope-v1"\nseeds = [1]',
            "unknown task 'Nope-v1'; valid choices: AssemblingKits-v1, LiftPegUpright-v1",
        ),
        ('task = "LiftPegUpright-v1"\nseeds = [1, 1]', "seeds repeat"),
        ('task = "LiftPegUpright-v1"\nseeds = "all"', "seeds must be a list"),
        (
            'task = "LiftPegUpright-v1"\nseeds = [1]\ncontrol_mode = "fast"',
            "unknown control_mode 'fast'; valid choices",
        ),
        ('task = "LiftPegUpright-v1"\nseeds = [1]\nepisodes = 3', "unknown key(s) episodes; valid keys"),
        ("seeds = [1]", "missing required key 'task'"),
        ('task = "LiftPegUpright-v1"\nseeds = [1', "invalid TOML"),
    ],
)
def test_bad_suite_files_name_the_file_and_the_problem(tmp_path, body, message):
    path = tmp_path / "bad.toml"
    path.write_text(body)
    with pytest.raises(ValueError) as err:
        load_suite(path)
    assert str(path) in str(err.value) and message in str(err.value)


def test_suite_cut_and_adhoc():
    suite = load_suite(ROOT / "eval/suites/lift_peg_upright.toml")
    assert suite.first(3).seeds == (1_000_000, 1_000_001, 1_000_002)
    with pytest.raises(ValueError, match="has 100 seeds; cannot run 101"):
        suite.first(101)
    assert adhoc_suite("AssemblingKits-v1", 2, seed=7).seeds == (7, 8)


# -- outcomes --------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def ak_env():
    env = gym.make("kitbench/AssemblingKits-v1")
    yield env
    env.close()


@pytest.fixture(scope="module")
def lpu_env():
    env = gym.make("kitbench/LiftPegUpright-v1")
    yield env
    env.close()


def _ak_info(pos, rot, slot, dist=0.1):
    return {
        "success": pos and rot and slot,
        "pos_correct": pos,
        "rot_correct": rot,
        "in_slot": slot,
        "pos_diff_norm": dist,
    }


@pytest.mark.parametrize(
    "info,ever,held,expected",
    [
        (_ak_info(True, True, True, 0.0), True, False, None),
        (_ak_info(True, True, False, 0.01), True, True, "not_inserted"),
        (_ak_info(True, False, False, 0.01), True, False, "misaligned"),
        (_ak_info(False, True, False, 0.04), True, True, "misaligned"),
        (_ak_info(False, False, False), False, False, "never_grasped"),
        (_ak_info(False, False, False), True, False, "dropped"),
        (_ak_info(False, False, False), True, True, "not_transported"),
    ],
)
def test_assembling_kits_failure_categories(ak_env, info, ever, held, expected):
    category = failure_category(ak_env, info, GraspHistory(ever, held))
    if expected == "dropped":  # the same end, the hand having opened as the grasp ended
        assert failure_category(ak_env, info, GraspHistory(ever, held, released=True)) == "released"
    assert category == expected
    assert category is None or category in ak_env.unwrapped.failure_categories


@pytest.mark.parametrize(
    "tilt,z,ever,held,expected",
    [
        (0.01, 0.001, True, True, None),
        (1.5, 0.1, False, False, "never_grasped"),
        (1.5, 0.1, True, False, "dropped"),
        (0.5, 0.001, True, True, "not_upright"),
        (0.01, 0.02, True, True, "wrong_height"),
    ],
)
def test_lift_peg_failure_categories(lpu_env, tilt, z, ever, held, expected):
    info = {
        "success": tilt < 0.08 and z < 0.005,
        "upright": tilt < 0.08,
        "at_height": z < 0.005,
        "tilt": tilt,
        "z_error": z,
    }
    assert failure_category(lpu_env, info, GraspHistory(ever, held)) == expected
    if expected == "dropped":
        assert failure_category(lpu_env, info, GraspHistory(ever, held, released=True)) == "released"


class _LetGoMidSwing:
    """The Panda's expert until `steps` into its swing; then it opens the hand (`how="open"`), or the peg is pulled
    out of the closed hand (`how="slip"`)."""

    def __init__(self, how: str, steps: int = 4):
        from kitbench.policies.expert import ExpertPolicy

        self.expert, self.how, self.steps = ExpertPolicy(), how, steps

    def reset(self, env, seed, obs, info):
        self.env, self.swinging = env, 0
        self.expert.reset(env, seed, obs, info)

    def act(self, obs):
        action = self.expert.act(obs)
        if self.expert.phase == "swing" or self.swinging:
            self.swinging += 1
        if self.swinging > self.steps:
            if self.how == "open":
                action[-1] = 1.0  # open (ManiSkill's sign)
            elif self.swinging == self.steps + 1:  # out of the fingers, as a slip ends
                import sapien

                from kitbench.tasks.lift_peg_upright import LYING_QUAT, PEG_HALF_WIDTH

                # lying on the table well clear of the hand
                self.env.unwrapped.peg.set_pose(sapien.Pose([0.0, 0.3, PEG_HALF_WIDTH], LYING_QUAT))
        return action


@pytest.mark.parametrize(("how", "expected"), [("open", "released"), ("slip", "dropped")])
def test_a_peg_let_go_mid_swing_is_released_and_one_pulled_from_the_closed_hand_dropped(how, expected):
    from kitbench.evaluation.episode import evaluate_episode

    env = gym.make("kitbench/LiftPegUpright-v1", control_mode="pd_joint_pos")
    try:
        result = evaluate_episode(env, _LetGoMidSwing(how), seed=1)
    finally:
        env.close()
    assert not result.success and result.failure == expected


def test_a_category_outside_the_tasks_list_is_a_bug(lpu_env, monkeypatch):
    monkeypatch.setattr(type(lpu_env.unwrapped), "failure_category", lambda self, info, grasp: "gremlins")
    with pytest.raises(RuntimeError, match="'gremlins', which is not in its failure_categories"):
        failure_category(lpu_env, {"success": False}, GraspHistory())


def _result(seed, success):
    return EpisodeResult(seed, success, 10, 10 if success else None, 0.0, {}, None if success else "dropped")


def test_videos_show_failures_and_successes_in_seed_order():
    results = [_result(s, s % 3 != 0) for s in range(9)]  # failures: 0, 3, 6
    assert [r.seed for r in pick_video_seeds(results, 4)] == [0, 1, 2, 3]
    assert [r.seed for r in pick_video_seeds(results, 3)] == [0, 1, 3]
    only_successes = [_result(s, True) for s in range(3)]
    assert [r.seed for r in pick_video_seeds(only_successes, 2)] == [0, 1]
    assert pick_video_seeds(results, 0) == []


# -- end to end ------------------------------------------------------------------------------------
REPORT_KEYS = {
    "report_version",
    "kitbench_version",
    "task",
    "policy",
    "suite",
    "episodes",
    "success",
    "criteria",
    "episode_length",
    "steps_to_success",
    "seconds_to_success",
    "return",
    "return_by_outcome",
    "failure_categories",
    "measurements",
    "per_episode",
    "output",
    "timing",
}


def _suite(task, n, **modes):
    name = "lift_peg_upright.toml" if task == "LiftPegUpright-v1" else "assembling_kits.toml"
    return load_suite(ROOT / "eval/suites" / name).first(n).with_modes(**modes)


@pytest.fixture(scope="module")
def expert_report(tmp_path_factory):
    out = tmp_path_factory.mktemp("eval") / "expert"
    return out, run_eval(EvalConfig.of(_suite("LiftPegUpright-v1", 6), "expert", out), progress=False)


def test_expert_report_has_every_field_and_scores_like_its_benchmark(expert_report):
    out, report = expert_report
    assert REPORT_KEYS <= set(report)
    assert report["success"]["rate"] == 1.0  # the expert benchmark: 500/500 seeds
    assert report["success"]["ci95"][0] > 0.5
    assert report["steps_to_success"]["max"] <= 50
    assert set(report["criteria"]) == {"upright", "at_height"}
    assert [e["seed"] for e in report["per_episode"]] == list(range(1_000_000, 1_000_006))
    on_disk = json.loads((out / "report.json").read_text())
    assert without_timing(on_disk) == json.loads(json.dumps(without_timing(report)))
    md = (out / "report.md").read_text()
    assert "**Success: 100.0% (6/6" in md and "Failures by category" in md
    assert {p.name for p in (out / "plots").iterdir()} == {
        "success.png",
        "episode_length.png",
        "return.png",
        "steps_to_success.png",
    }


def test_the_report_says_where_the_tasks_measurements_start_and_end(expert_report):
    """The expert stands every lying peg upright: its tilt from vertical starts at a right angle and ends within
    the success test's; each episode keeps its own start beside its end."""
    out, report = expert_report
    tilt = report["measurements"]["tilt"]
    assert tilt["start"]["n"] == tilt["end"]["n"] == 6 and tilt["end_of_failures"] is None
    assert tilt["start"]["min"] > math.radians(80) and tilt["end"]["max"] < MAX_TILT
    for episode in report["per_episode"]:
        assert episode["initial"]["tilt"] > math.radians(80) and not episode["initial"]["success"]
    assert "## The task's measurements at the start and the end" in (out / "report.md").read_text()


def test_random_policy_scores_zero_and_failures_are_categorised(tmp_path):
    report = run_eval(EvalConfig.of(_suite("LiftPegUpright-v1", 4), "random", tmp_path), progress=False)
    assert report["success"]["count"] == 0
    assert sum(report["failure_categories"].values()) == 4
    assert all(e["length"] == 50 for e in report["per_episode"])


def test_two_workers_give_the_same_report_as_one(tmp_path):
    suite = _suite("AssemblingKits-v1", 4)
    one = run_eval(EvalConfig.of(suite, "random", tmp_path / "w1"), progress=False)
    two = run_eval(EvalConfig.of(suite, "random", tmp_path / "w2", workers=2), progress=False)
    assert without_timing(one) == without_timing(two)
    assert {row["shape_id"] for row in one["per_shape"]} == {e["config"]["shape_id"] for e in one["per_episode"]}
    assert set(one["criteria"]) == {"pos_correct", "rot_correct", "in_slot"}


def test_same_suite_same_numbers(expert_report, tmp_path):
    _, first = expert_report
    again = run_eval(EvalConfig.of(_suite("LiftPegUpright-v1", 6), "expert", tmp_path), progress=False)
    assert without_timing(again) == without_timing(first)


def test_videos_replay_the_scored_episodes(tmp_path, needs_vulkan):
    report = run_eval(EvalConfig.of(_suite("LiftPegUpright-v1", 2), "expert", tmp_path, videos=1), progress=False)
    (video,) = report["output"]["videos"]
    assert video["matches_scored_episode"] and video["success"]
    import av

    with av.open(str(tmp_path / video["path"])) as container:
        frames = sum(1 for _ in container.decode(video=0))
    assert frames == report["per_episode"][0]["length"] + 1  # the reset state and one frame per step
    # the wall time covers every part, the video pass included, and the rate is over the wall time
    timing = report["timing"]
    parts = ("setup_seconds", "scoring_seconds", "report_seconds", "video_seconds")
    assert all(timing[p] > 0 for p in parts)
    assert sum(timing[p] for p in parts) == pytest.approx(timing["seconds"], abs=0.05)
    scored_and_reported = timing["seconds"] - timing["video_seconds"]
    assert timing["episodes_per_minute"] == pytest.approx(60.0 * 2 / scored_and_reported, rel=1e-6)
    text = (tmp_path / "report.md").read_text()
    assert f"Evaluated in {timing['seconds']:.1f} s wall time" in text and "videos " in text


# -- command line ----------------------------------------------------------------------------------
def _cli(*args):
    return launch.run(
        [sys.executable, "-m", "kitbench.cli", "eval", *args], capture_output=True, text=True, timeout=600, cwd=ROOT
    )


@pytest.mark.parametrize(
    "args,message",
    [
        (
            ["--task", "LiftPegUpright-v1", "--episodes", "2", "--policy", "clever"],
            "unknown policy 'clever'; valid choices",
        ),
        (["--task", "Nope-v1", "--episodes", "2"], "unknown task 'Nope-v1'; valid choices"),
        (["--task", "LiftPegUpright-v1"], "missing --episodes"),
        (["--suite", "eval/suites/lift_peg_upright.toml", "--seed", "3"], "--seed and --suite exclude each other"),
        (["--suite", "eval/suites/lift_peg_upright.toml", "--task", "AssemblingKits-v1"], "does not match suite"),
        (["--task", "LiftPegUpright-v1", "--episodes", "2", "--control-mode", "warp"], "unknown control_mode 'warp'"),
        (["--task", "LiftPegUpright-v1", "--episodes", "2", "--workers", "0"], "workers must be a positive integer"),
        (["--task", "LiftPegUpright-v1", "--episodes", "2", "--policy", "replay:/nonexistent"], "no LeRobot dataset"),
    ],
)
def test_cli_bad_input_is_refused_and_nothing_is_written(tmp_path, args, message):
    out = tmp_path / "report"
    result = _cli(*args, "--out", str(out))
    assert result.returncode == 2, result.stderr
    assert message in result.stderr
    assert not out.exists()


def test_cli_runs_a_suite_and_prints_the_summary(tmp_path):
    result = _cli(
        "--suite",
        "eval/suites/lift_peg_upright_short.toml",
        "--episodes",
        "2",
        "--policy",
        "zero",
        "--out",
        str(tmp_path),
    )
    assert result.returncode == 0, result.stderr
    assert "LiftPegUpright-v1 · zero · 2 episodes: success 0.0%" in result.stdout
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["suite"]["name"] == "lift_peg_upright_short" and report["failure_categories"]["never_grasped"] == 2


def test_suite_settings_are_validated_like_files():
    with pytest.raises(ValueError, match="unknown obs_mode 'thermal'; valid choices: state, rgb, rgbd, depth"):
        Suite(name="x", task="LiftPegUpright-v1", seeds=(1,), obs_mode="thermal")


def test_histograms_count_in_whole_episodes_keep_the_legend_off_the_bars_and_say_when_empty():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from kitbench.evaluation.plots import draw_histogram

    fig, (full, empty) = plt.subplots(1, 2)
    draw_histogram(full, [27, 28, 28], [200], "control steps")
    draw_histogram(empty, [], [], "control steps to first success")
    fig.canvas.draw()
    ticks = full.get_yticks()
    assert len(ticks) >= 2 and all(float(t).is_integer() for t in ticks)
    legend = full.get_legend()
    assert [t.get_text() for t in legend.get_texts()] == ["success", "failure"]
    renderer = fig.canvas.get_renderer()
    assert legend.get_window_extent(renderer).x0 >= full.get_window_extent(renderer).x1  # beside the axes
    assert [t.get_text() for t in empty.texts] == ["no episode to show"] and empty.get_legend() is None
    plt.close(fig)
