"""Demonstrations made for learning: action noise (DART) and settling after success, in the rollout and through
`kitbench record`."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
from sapien import physx

import kitbench  # noqa: F401  (registers the tasks)
from kitbench.control.controllers import controller_class
from kitbench.metadata import RECORDING_FILE
from kitbench.policies.expert import ExpertPolicy
from kitbench.recording.config import RecordConfig, validate
from kitbench.recording.rollout import run_episode

LPU = "kitbench/LiftPegUpright-v1"


def _stack(record, key):
    return np.stack([f[key] for f in record.frames])


@pytest.mark.parametrize("mode", ["pd_joint_delta_pos", "pd_joint_pos", "pd_ee_delta_pose"])
def test_noise_perturbs_executed_actions_and_keeps_clean_labels(mode):
    env = gym.make(LPU, control_mode=mode)
    record = run_episode(env, ExpertPolicy(), seed=3, action_noise=1.0)
    labels, executed = _stack(record, "action"), _stack(record, "executed_action")
    arm = slice(0, labels.shape[1] - 1)
    noise = (executed - labels)[:, arm]
    # a unit in the action's own units (ManiSkill's normalised deltas: 0.02 rad is 0.2)
    unit = np.asarray(controller_class(mode).noise_units) * env.unwrapped.arm_action_scale()
    assert np.all(np.abs(noise).max(axis=0) > 0)  # every arm dimension is perturbed
    # clipping at the action box only shrinks noise, so its spread is at most the unit and not far below it
    assert np.all(noise.std(axis=0) < 1.3 * unit) and np.all(noise.std(axis=0) > 0.5 * unit)
    np.testing.assert_array_equal(executed[:, -1], labels[:, -1])  # the gripper is never perturbed


def test_labels_are_what_the_expert_commands_from_the_perturbed_states():
    """Replaying the executed actions reproduces the perturbed states (physics is deterministic), and in each of
    them a fresh expert commands exactly the recorded label: the labels are the expert's corrections."""
    record = run_episode(gym.make(LPU), ExpertPolicy(), seed=5, action_noise=1.5)
    labels, executed = _stack(record, "action"), _stack(record, "executed_action")
    assert not np.allclose(labels, executed)
    env = gym.make(LPU)
    obs, info = env.reset(seed=5)
    expert = ExpertPolicy()
    expert.reset(env, 5, obs, info)
    for label, action in zip(labels, executed, strict=True):
        np.testing.assert_array_equal(expert.act(obs), label)
        obs, *_ = env.step(action)


def test_noise_is_deterministic_in_the_seed():
    a = run_episode(gym.make(LPU), ExpertPolicy(), seed=7, action_noise=1.0)
    b = run_episode(gym.make(LPU), ExpertPolicy(), seed=7, action_noise=1.0)
    c = run_episode(gym.make(LPU), ExpertPolicy(), seed=8, action_noise=1.0)
    np.testing.assert_array_equal(_stack(a, "executed_action"), _stack(b, "executed_action"))
    np.testing.assert_array_equal(_stack(a, "observation.state"), _stack(b, "observation.state"))
    first = min(a.length, c.length)
    noise_a = (_stack(a, "executed_action") - _stack(a, "action"))[:first]
    noise_c = (_stack(c, "executed_action") - _stack(c, "action"))[:first]
    assert not np.allclose(noise_a, noise_c)


class _PhaseLog(ExpertPolicy):
    """The expert, noting the phase each of its actions belongs to."""

    def reset(self, env, seed, obs, info):
        super().reset(env, seed, obs, info)
        self.played: list[str] = []

    def act(self, obs):
        action = super().act(obs)
        self.played.append(self.phase)
        return action


def test_noise_runs_only_in_the_named_phases_and_is_deterministic():
    """Noise confined to the carry and the re-aim over the slot: every step played in those phases is perturbed,
    no other step is (approach, grasp, insertion, release), and the same seed gives the same episode."""
    phases = ("transport", "align")
    runs = []
    for _ in range(2):
        policy = _PhaseLog()
        env = gym.make("kitbench/AssemblingKits-v1", control_mode="pd_joint_pos")
        record = run_episode(env, policy, seed=1, action_noise=1.0, noise_phases=phases, settle_steps=4)
        runs.append((record, policy.played))
    (record, played), (again, _) = runs
    labels, executed = _stack(record, "action"), _stack(record, "executed_action")
    perturbed = np.abs(executed - labels)[:, :-1].max(axis=1) > 0
    in_phases = np.isin(played, phases)
    assert {"approach", "grasp", "transport", "insert", "release"} <= set(played)
    assert in_phases.sum() > 5 and record.first_success > np.flatnonzero(in_phases).max()
    np.testing.assert_array_equal(perturbed, in_phases)
    np.testing.assert_array_equal(_stack(again, "executed_action"), executed)
    np.testing.assert_array_equal(
        _stack(again, "observation.environment_state"), _stack(record, "observation.environment_state")
    )


@pytest.mark.parametrize(
    "task,robot,seeds",
    [
        ("AssemblingKits-v1", None, (0, 1, 2)),
        ("LiftPegUpright-v1", "panda", (0, 1)),
        ("LiftPegUpright-v1", "fetch", (0,)),
    ],
)
def test_every_phase_an_expert_plays_is_one_it_declares(task, robot, seeds):
    """`--noise-phases` is checked against the planner's `phases`: a phase played but not declared could never
    be named, so the declaration must cover every phase an episode meets (with noise, the retries too)."""
    from kitbench.registration import make_env

    env = make_env(task, control_mode="pd_joint_pos", robot_uids=robot)
    declared = type(env.unwrapped).expert_class(robot).phases
    played: set[str] = set()
    for seed in seeds:
        for noise in (0.0, 2.0):
            policy = _PhaseLog()
            run_episode(env, policy, seed=seed, action_noise=noise)
            played |= set(policy.played)
    assert played <= set(declared), sorted(played - set(declared))
    assert {"approach", "grasp", "swing" if task.startswith("Lift") else "insert"} <= played


def test_settling_runs_k_steps_past_the_first_success():
    # absolute joint targets: the expert succeeds by step ~30 of 50, leaving room to settle
    plain = run_episode(gym.make(LPU, control_mode="pd_joint_pos"), ExpertPolicy(), seed=2)
    settled = run_episode(gym.make(LPU, control_mode="pd_joint_pos"), ExpertPolicy(), seed=2, settle_steps=6)
    assert plain.success and plain.length == plain.first_success + 1  # the task ends an episode at success
    assert settled.first_success == plain.first_success
    assert settled.length == plain.length + 6
    # the steps up to the success are the same episode
    np.testing.assert_array_equal(_stack(settled, "action")[: plain.length], _stack(plain, "action"))
    done = _stack(settled, "next.done")[:, 0]
    assert done[-1] and not done[:-1].any()
    assert _stack(settled, "next.success")[plain.first_success :, 0].all()  # the peg stays upright in the hand


def test_settling_keeps_a_seated_shape_a_success_through_the_release():
    """AssemblingKits demonstrations otherwise end at insertion, the gripper still closed: settling records the
    expert letting go, and the shape stays seated."""
    env = gym.make("kitbench/AssemblingKits-v1", control_mode="pd_joint_pos")
    record = run_episode(env, ExpertPolicy(), seed=0, settle_steps=12)
    assert record.success and record.length == record.first_success + 1 + 12
    gripper = _stack(record, "action")[:, -1]
    assert gripper[record.first_success] < 0 and gripper[-1] > 0  # closed at success, open by the end (+1 opens)
    assert _stack(record, "next.success")[record.first_success :, 0].all()


def test_settling_sets_the_peg_down_and_lets_go():
    """LiftPegUpright demonstrations otherwise end with the peg held 2 mm above the table: settling records the
    expert pressing it onto the table and opening the hand; the peg then stands by itself, its height fixed by
    the table, and stays a success."""
    env = gym.make(LPU, control_mode="pd_joint_pos")
    record = run_episode(env, ExpertPolicy(), seed=4, settle_steps=14)
    assert record.success and record.length == record.first_success + 1 + 14
    gripper = _stack(record, "action")[:, -1]
    assert gripper[record.first_success] < 0 and gripper[-1] > 0  # ManiSkill's sign: +1 opens
    assert _stack(record, "next.success")[record.first_success :, 0].all()
    u = env.unwrapped
    assert not u.robot.is_grasping(u.target_object)
    assert abs(float(u.target_object.pose.p[2]) - 0.12) < 0.001  # resting on the table: half its length up
    body = u.target_object.find_component_by_type(physx.PhysxRigidDynamicComponent)
    assert np.linalg.norm(body.linear_velocity) < 0.01 and np.linalg.norm(body.angular_velocity) < 0.05


def test_settling_stops_when_time_runs_out():
    record = run_episode(gym.make(LPU, control_mode="pd_joint_pos"), ExpertPolicy(), seed=2, settle_steps=40)
    assert record.success and record.length == 50  # the task's step limit
    assert _stack(record, "next.done")[-1, 0]


def test_record_stores_the_options_and_clean_labels(tmp_path):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from kitbench.recording.recorder import record

    out = tmp_path / "noisy"
    config = RecordConfig.of(
        task="LiftPegUpright-v1", episodes=2, out=out, action_noise=1.0, settle_steps=3, mcap=False
    )
    summary = record(config, progress=False)
    assert summary.stored == 2
    settings = json.loads((out / RECORDING_FILE).read_text())
    assert settings["action_noise"] == 1.0 and settings["settle_steps"] == 3
    ds = LeRobotDataset("kitbench/LiftPegUpright-v1", root=out)
    labels = np.stack([ds[i]["action"].numpy() for i in range(ds.num_frames)])
    executed = np.stack([ds[i]["executed_action"].numpy() for i in range(ds.num_frames)])
    assert not np.allclose(labels, executed)
    # a resumed recording must use the same demonstration options
    with pytest.raises(ValueError, match=r"settle_steps: recorded 3, asked 0"):
        validate(RecordConfig.of(task="LiftPegUpright-v1", episodes=3, out=out, action_noise=1.0, resume=True))


def test_record_stores_the_noise_phases_from_a_recipe(tmp_path):
    from kitbench.recording.config import load_recipe
    from kitbench.recording.recorder import record

    out = tmp_path / "phased"
    recipe = tmp_path / "recipe.toml"
    recipe.write_text(
        f'[record]\ntask = "LiftPegUpright-v1"\nepisodes = 1\nout = "{out}"\ncontrol_mode = "pd_joint_pos"\n'
        'action_noise = 1.0\nnoise_phases = ["swing"]\nmcap = false\n'
    )
    config = load_recipe(recipe)
    assert config.demo.noise_phases == ("swing",)
    assert record(config, progress=False).stored == 1
    assert json.loads((out / RECORDING_FILE).read_text())["noise_phases"] == ["swing"]
    validate(load_recipe(recipe, resume=True, episodes=2))  # the same phases resume
    with pytest.raises(ValueError, match=r"noise_phases: recorded \['swing'\], asked \['swing', 'place'\]"):
        validate(load_recipe(recipe, resume=True, episodes=2, noise_phases=["swing", "place"]))


def test_noise_phases_for_an_expert_that_declares_none_say_so(tmp_path, monkeypatch):
    from kitbench.planning.assembling_kits import AssemblingKitsPlanner

    monkeypatch.setattr(AssemblingKitsPlanner, "phases", ())
    config = RecordConfig.of(
        task="AssemblingKits-v1", episodes=1, out=tmp_path / "never", action_noise=0.5, noise_phases=("insert",)
    )
    with pytest.raises(ValueError, match=r"^noise_phases: the AssemblingKits-v1 expert declares no phases"):
        validate(config)
    assert not (tmp_path / "never").exists()


PANDA_PHASES = "approach, descend, grasp, regrasp, swing, place, set_down, release, done, failed"
FETCH_PHASES = "approach, insert, grasp, swing, place, done, failed"


@pytest.mark.parametrize(
    "options,needle",
    [
        ({"action_noise": -0.5}, "action_noise must be a finite number >= 0 (0: no noise), got -0.5"),
        (
            {"action_noise": 0.5, "noise_phases": ("swing", "insert")},
            f"unknown noise phase 'insert' for the LiftPegUpright-v1 expert; valid choices: {PANDA_PHASES}",
        ),
        (
            {"action_noise": 0.5, "noise_phases": ("descend",), "robot": "fetch"},
            f"unknown noise phase 'descend' for the LiftPegUpright-v1 expert; valid choices: {FETCH_PHASES}",
        ),
        (
            {"noise_phases": ("swing",)},
            "noise_phases needs action_noise > 0: it names the expert phases the noise runs in",
        ),
        (
            {"action_noise": 0.5, "noise_phases": ("swing",), "policy": "random"},
            "noise_phases names phases of the expert; policy 'random' has none",
        ),
        ({"action_noise": 0.5, "noise_phases": ()}, "noise_phases must be a non-empty list of phase names, got ()"),
        (
            {"action_noise": 0.5, "noise_phases": "swing"},
            "noise_phases must be a non-empty list of phase names, got 'swing'",
        ),
        ({"action_noise": float("nan")}, "action_noise must be a finite number >= 0 (0: no noise), got nan"),
        ({"settle_steps": -1}, "settle_steps must be an integer >= 0, got -1"),
        ({"settle_steps": 2.5}, "settle_steps must be an integer >= 0, got 2.5"),
    ],
)
def test_bad_demonstration_options_are_refused_before_anything_is_written(tmp_path, options, needle):
    out = tmp_path / "never"
    with pytest.raises(ValueError) as err:
        validate(RecordConfig.of(task="LiftPegUpright-v1", episodes=1, out=out, **options))
    assert str(err.value) == needle
    assert not out.exists()
