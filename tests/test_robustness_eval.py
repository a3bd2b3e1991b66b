"""Evaluation's two success metrics and robustness suites: `success_once` and `success_at_end` on episodes
built to succeed and then fail, suites that declare perturbations, the report's robustness section, its plot and
`kitbench compare` on it."""

from __future__ import annotations

import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import kitbench  # noqa: F401  (registers the tasks)
from kitbench.errors import KitbenchError
from kitbench.evaluation.compare import compare_reports
from kitbench.evaluation.config import EvalConfig
from kitbench.evaluation.episode import evaluate_episode
from kitbench.evaluation.runner import run_eval
from kitbench.evaluation.suite import Suite, load_suite
from kitbench.policies.expert import ExpertPolicy

ROOT = Path(__file__).resolve().parents[1]
LPU = "LiftPegUpright-v1"


class LiftAfterSuccess(ExpertPolicy):
    """The expert until the task first succeeds, then it raises the peg it holds 10 cm: successful once, not at
    the end."""

    def reset(self, env, seed, obs, info):
        super().reset(env, seed, obs, info)
        self.done = False

    def act(self, obs):
        u = self._env.unwrapped
        self.done = self.done or bool(u.evaluate()["success"])
        if not self.done:
            return super().act(obs)
        # shoulder up, elbow out by 0.1 rad a step (ManiSkill's normalised deltas), the hand closed: it rises
        return np.array([0, -1.0, 0, 1.0, 0, 0, 0, -1], dtype=np.float32)


def _env(**kwargs):
    return gym.make(f"kitbench/{LPU}", control_mode="pd_joint_target_delta_pos", **kwargs)


# -- success_once and success_at_end on constructed episodes ---------------------------------------------
def test_without_settling_an_episode_ends_at_its_first_success_and_both_metrics_agree():
    result = evaluate_episode(_env(), LiftAfterSuccess(), 1_000_000)
    assert result.success and result.success_once and result.success_at_end
    assert result.length == result.steps_to_success and result.failure is None


def test_settling_after_success_then_losing_it_is_success_once_but_not_at_end():
    result = evaluate_episode(_env(), LiftAfterSuccess(), 1_000_000, settle_steps=8)
    assert result.success_once and not result.success_at_end
    assert not result.success  # the headline of a settled suite is success at the end
    assert result.length == result.steps_to_success + 8
    # the task's category for its last state: still held, no longer upright at its height
    assert result.failure in ("not_upright", "wrong_height")
    assert not all(result.criteria.values())


def test_settling_a_held_success_keeps_it_to_the_end():
    result = evaluate_episode(_env(), ExpertPolicy(), 1_000_000, settle_steps=8)
    assert result.success and result.success_once and result.success_at_end
    assert result.length == result.steps_to_success + 8


def test_settling_stops_at_the_time_limit():
    result = evaluate_episode(_env(), ExpertPolicy(), 1_000_000, settle_steps=1_000)
    assert result.length == 50 and result.success_at_end


def test_a_never_successful_episode_fails_both_metrics():
    from kitbench.policies.baselines import ZeroPolicy

    result = evaluate_episode(_env(), ZeroPolicy(), 1_000_000, settle_steps=5)
    assert not (result.success or result.success_once or result.success_at_end)
    assert result.failure == "never_grasped"


# -- suites ---------------------------------------------------------------------------------------------
def _write_suite(tmp_path: Path, body: str) -> Path:
    path = tmp_path / "suite.toml"
    path.write_text(f'[suite]\ntask = "{LPU}"\nseeds = [1000000, 1000001]\n' + body)
    return path


def test_a_suite_file_declares_perturbations_and_settle_steps():
    suite = load_suite(ROOT / "eval" / "suites" / "lift_peg_upright_robustness.toml")
    assert suite.conditions[0] is None and ("action_delay", 2) in suite.conditions
    assert suite.headline == "success_once"
    assert suite.to_dict()["perturbations"]["object_mass"] == [-50.0, 100.0]
    for name in ("assembling_kits_robustness", "lift_peg_upright_robustness_rgb"):
        assert load_suite(ROOT / "eval" / "suites" / f"{name}.toml").perturbations
    settled = Suite(name="s", task=LPU, seeds=(1,), settle_steps=10)
    assert settled.headline == "success_at_end"


@pytest.mark.parametrize(
    ("body", "message"),
    [
        ("[suite.perturbations]\nwind = [1]\n", r"suite .*: unknown perturbation 'wind'; valid choices: "),
        ("[suite.perturbations]\nobject_mass = [-95]\n", r"object_mass: level -95 is outside"),
        ("[suite.perturbations]\nobject_mass = [10, 10]\n", r"perturbation object_mass repeats a level"),
        ("[suite.perturbations]\nobject_mass = []\n", r"perturbation object_mass has no levels"),
        ("[suite.perturbations]\ncamera_pose = [1]\n", r"camera_pose changes camera images only; obs_mode 'state'"),
        ("settle_steps = -1\n", r"settle_steps must be an integer >= 0, got -1"),
    ],
)
def test_bad_suite_perturbations_are_refused_naming_the_file(tmp_path, body, message):
    with pytest.raises(KitbenchError, match=message) as caught:
        load_suite(_write_suite(tmp_path, body))
    assert "\n" not in str(caught.value)


# -- the report -----------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def robustness_report(tmp_path_factory):
    suite = Suite(
        name="robust",
        task=LPU,
        seeds=(1_000_000, 1_000_001, 1_000_002),
        perturbations=(("action_delay", (1,)), ("object_mass", (100,))),
    )
    out = tmp_path_factory.mktemp("robust")
    report = run_eval(EvalConfig.of(suite, "expert", out), progress=False)
    return out, report


def test_the_report_scores_every_condition_on_the_same_seeds(robustness_report):
    out, report = robustness_report
    conditions = [(c["perturbation"], c["level"]) for c in report["robustness"]]
    assert conditions == [("action_delay", 1), ("object_mass", 100.0)]
    for c in report["robustness"]:
        assert [e["seed"] for e in c["per_episode"]] == list(report["suite"]["seeds"])
        assert c["episodes"] == 3 and c["unit"]
    delay = report["robustness"][0]
    # the expert checks its grasp the step after closing: a step of delay defeats it (0 of 3), and the report
    # says so against the nominal 3 of 3, with McNemar's p for 3 lost seeds and none gained
    assert report["success"]["count"] == 3 and delay["success"]["count"] == 0
    assert delay["vs_nominal"] == {"difference": -1.0, "seeds_lost": 3, "seeds_gained": 0, "p_value": 0.25}
    assert report["robustness"][1]["success"]["count"] == 3
    md = (out / "report.md").read_text()
    assert "## Robustness" in md and "| action_delay | 1 steps | 0% (0%–56%) | -100% | 3 / 0 | 0.25 |" in md
    assert (out / "plots" / "robustness.png").is_file()
    assert report["headline"] == "success_once" and "success_at_end" in report


def test_a_perturbed_seed_scores_as_the_perturbed_env_plays_it(robustness_report):
    """The eval's condition is the env option: the same seed played with gym.make(perturbations=...) matches."""
    _, report = robustness_report
    mass = report["robustness"][1]
    for entry in mass["per_episode"]:
        direct = evaluate_episode(_env(perturbations={"object_mass": 100}), ExpertPolicy(), entry["seed"])
        assert (direct.success, direct.failure) == (entry["success"], entry["failure"])


def test_compare_pairs_each_condition_on_its_seeds(robustness_report, tmp_path):
    out, report = robustness_report
    worse = json.loads(json.dumps(report))
    for entry in worse["robustness"][1]["per_episode"]:
        entry["success"] = False
    worse["robustness"][1]["success"] = {"count": 0, "episodes": 3, "rate": 0.0, "ci95": [0.0, 0.56]}
    (tmp_path / "b.json").write_text(json.dumps(worse))
    comparison = compare_reports(out / "report.json", tmp_path / "b.json")
    rows = {row.label: row for row in comparison.rows}
    mass = rows["perturbation object_mass 100 %"]
    assert mass.paired is not None and (mass.paired.a_only, mass.paired.b_only) == (3, 0)
    assert mass.paired_p == pytest.approx(0.25)
    assert rows["perturbation action_delay 1 steps"].difference == 0
