"""`kitbench sweep`: one policy over a grid of execution settings, each cell an ordinary report whose provenance holds
the settings in force, combinations the policy refuses skipped with their reason; and `--action-delay`, the
inference latency a cell may set, executing each action that many control steps late."""

from __future__ import annotations

import json
import pickle
import re
from pathlib import Path

import numpy as np
import pytest

from kitbench.cli import main
from kitbench.errors import KitbenchError
from kitbench.evaluation.config import EvalConfig
from kitbench.evaluation.runner import run_eval
from kitbench.evaluation.suite import adhoc_suite, load_suite
from kitbench.evaluation.work import EvalWork, make_suite_env
from kitbench.rollout import Hook, OneEpisode, run

ROOT = Path(__file__).resolve().parents[1]
SHORT = "lift_peg_upright_short"
GRID = ("--grid", "n_action_steps=1,5", "--grid", "temporal_ensemble=on,off")
CELLS = {  # scored cells: (n_action_steps, temporal_ensemble_coeff) in force
    "n_action_steps=1_temporal_ensemble=on": (1, 0.01),
    "n_action_steps=1_temporal_ensemble=off": (1, None),
    "n_action_steps=5_temporal_ensemble=off": (5, None),
}
REFUSED = "n_action_steps=5_temporal_ensemble=on"  # ACT ensembles with n_action_steps 1 only


def _sweep(policy: str, out: Path, *extra: str) -> int:
    args = ["sweep", "--policy", policy, "--suite", SHORT, "--episodes", "1", "--device", "cpu", "--out", str(out)]
    return main([*args, *extra])


@pytest.fixture(scope="module")
def swept(tiny_act_run, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("sweep") / "sw"
    assert _sweep(f"lerobot:{tiny_act_run}", out, *GRID, "--action-delay", "1") == 0
    return out


def test_each_cell_is_a_report_whose_provenance_holds_its_settings(swept):
    assert sorted(p.name for p in swept.iterdir() if p.is_dir()) == sorted(CELLS)
    for name, (steps, coeff) in CELLS.items():
        report = json.loads((swept / name / "report.json").read_text())
        execution = report["provenance"]["execution"]
        assert (execution["n_action_steps"], execution["temporal_ensemble_coeff"]) == (steps, coeff)
        assert execution["action_delay"] == 1  # the command line's, in every cell
        assert execution["policy_options"] == {"n_action_steps": steps, "temporal_ensemble_coeff": coeff}
        assert report["suite"]["seeds"] == list(load_suite(ROOT / "eval/suites" / f"{SHORT}.toml").seeds[:1])
    summary = json.loads((swept / "sweep.json").read_text())
    rows = {r["cell"]: r for r in summary["rows"]}
    assert list(rows) == [
        "n_action_steps=1_temporal_ensemble=on",
        "n_action_steps=1_temporal_ensemble=off",
        REFUSED,
        "n_action_steps=5_temporal_ensemble=off",
    ]  # grid order
    assert (
        rows[REFUSED]["status"] == "skipped" and "must be 1 when using temporal ensembling" in rows[REFUSED]["reason"]
    )
    for name, (steps, coeff) in CELLS.items():
        assert rows[name]["execution"] == {"n_action_steps": steps, "temporal_ensemble_coeff": coeff, "action_delay": 1}
    md = (swept / "sweep.md").read_text()
    assert md.count("\n| ") == 5 and "skipped: " in md  # a header and a row per cell
    assert (swept / "sweep.png").stat().st_size > 1000


def test_a_finished_sweep_resumed_is_kept_and_other_settings_are_refused(swept, tiny_act_run, capsys):
    stamps = {p: p.stat().st_mtime_ns for p in swept.glob("*/report.json")}
    before = json.loads((swept / "sweep.json").read_text())
    assert _sweep(f"lerobot:{tiny_act_run}", swept, *GRID, "--action-delay", "1", "--resume") == 0
    assert {p: p.stat().st_mtime_ns for p in swept.glob("*/report.json")} == stamps
    assert json.loads((swept / "sweep.json").read_text()) == before
    assert _sweep(f"lerobot:{tiny_act_run}", swept, *GRID, "--action-delay", "2", "--resume") == 2
    assert "action_delay: report 1, now 2" in capsys.readouterr().err
    assert _sweep(f"lerobot:{tiny_act_run}", swept, *GRID, "--action-delay", "1") == 2
    assert "holds a sweep already; continue it with --resume" in capsys.readouterr().err


@pytest.mark.parametrize(
    "grid,message",
    [
        (["--grid", "n_action_steps=6,7"], "every cell of the grid is refused; the first: .*n_action_steps"),
        (["--grid", "temporal_ensemble=on,maybe"], "temporal_ensemble value 'maybe'; valid choices: on, off"),
        (["--grid", "action_delay=0,-1"], "action_delay must be a whole number of control steps from 0 to 20"),
        (["--grid", "action_delay=0,1", "--action-delay", "1"], "--grid action_delay and --action-delay set the same"),
        (
            ["--grid", "temporal_ensemble=on,off", "--policy-option", "temporal_ensemble_coeff=0.1"],
            "--policy-option tem",
        ),
        (["--grid", "n_action_steps=1", "--grid", "n_action_steps=2"], "--grid n_action_steps is given twice"),
        (["--grid", "n_action_steps"], "is not KEY=V1,V2"),
        (["--grid", "chunk_sise=1,2"], "every cell of the grid is refused; the first: .*valid choices: .*chunk_size"),
        ([], "give at least one --grid"),
    ],
    ids=[
        "all-refused",
        "switch",
        "delay",
        "delay-twice",
        "ensemble-twice",
        "key-twice",
        "no-values",
        "unknown-key",
        "no-grid",
    ],
)
def test_bad_grids_are_refused_in_one_line_writing_nothing(tiny_act_run, tmp_path, capsys, grid, message):
    out = tmp_path / "sw"
    assert _sweep(f"lerobot:{tiny_act_run}", out, *grid) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and re.search(message, err), err
    assert not out.exists()


# -- the inference latency ---------------------------------------------------------------------------------
class Targets(Hook):
    """The arm's joint targets after each step."""

    def __init__(self):
        self.seen: list[np.ndarray] = []

    def after_step(self, episode, step) -> None:
        self.seen.append(episode.env.unwrapped.robot.arm_targets())


class Ramp:
    """Joint targets that move 0.02 rad further every step, from the observed joint positions at the reset."""

    name = "ramp"

    def reset(self, env, seed, obs, info):
        self.start, self.k = np.asarray(obs[:7], dtype=np.float32), 0
        self.sent: list[np.ndarray] = []

    def act(self, obs):
        self.k += 1
        self.sent.append(np.append(self.start + 0.02 * self.k, 1.0).astype(np.float32))
        return self.sent[-1]


@pytest.mark.parametrize("delay", [0, 2])
def test_the_eval_env_executes_each_action_delay_steps_late(delay):
    suite = adhoc_suite("LiftPegUpright-v1", 1, control_mode="pd_joint_pos")
    env = make_suite_env(suite, action_delay=delay)
    policy, targets = Ramp(), Targets()
    run([env], [suite.seeds[0]], OneEpisode(policy), lambda _: [targets])
    env.close()
    steps = len(targets.seen)
    assert steps > delay + 3
    for t in range(delay, steps):
        np.testing.assert_allclose(targets.seen[t], policy.sent[t - delay][:7], atol=1e-5)
    for t in range(delay):  # nothing computed yet: the robot holds its first targets
        np.testing.assert_allclose(targets.seen[t], targets.seen[0], atol=1e-6)
        assert not np.allclose(targets.seen[t], policy.sent[t][:7], atol=1e-3)


def test_workers_get_the_delay():
    work = pickle.loads(pickle.dumps(EvalWork(adhoc_suite("LiftPegUpright-v1", 1), "expert", action_delay=3)))
    assert work.action_delay == 3


def test_a_delayed_expert_scores_other_episodes_and_its_report_says_so(tmp_path):
    suite = adhoc_suite("LiftPegUpright-v1", 1)
    reports = {d: run_eval(EvalConfig.of(suite, "expert", tmp_path / str(d), action_delay=d), False) for d in (0, 4)}
    assert [reports[d]["provenance"]["execution"]["action_delay"] for d in (0, 4)] == [0, 4]
    now, late = (reports[d]["per_episode"][0] for d in (0, 4))
    assert (now["length"], now["episode_return"]) != (late["length"], late["episode_return"])
    assert "action_delay 4" in (tmp_path / "4" / "report.md").read_text()


@pytest.mark.parametrize(
    "suite,settings,message",
    [
        ("lift_peg_upright_robustness", {}, "set the same latency; drop one"),
        ("lift_peg_upright_short", {"save_dataset": Path("ds")}, "--save-dataset stores each frame's executed action"),
        ("lift_peg_upright_short", {"action_delay": 21}, "from 0 to 20, got 21"),
    ],
)
def test_a_delay_that_cannot_hold_is_refused(suite, settings, message, tmp_path):
    config = EvalConfig.of(load_suite(ROOT / "eval/suites" / f"{suite}.toml"), "expert", tmp_path / "r")
    config = config.replace(**{"action_delay": 2, **settings})
    with pytest.raises(KitbenchError, match=re.escape(message) if "--" in message else message):
        run_eval(config, False)
    assert not (tmp_path / "r").exists()
