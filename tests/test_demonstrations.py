"""Demonstrations made for learning: action noise (DART) and settling after success, in the rollout and through
`kitbench record`."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
from sapien import physx

import kitbench  # noqa: F401  (registers the tasks)
from kitbench.metadata import RECORDING_FILE
from kitbench.policies.expert import ExpertPolicy
from kitbench.recording.config import RecordConfig, validate
from kitbench.recording.noise import NOISE_UNITS
from kitbench.recording.rollout import run_episode

LPU = "kitbench/LiftPegUpright-v1"


def _stack(record, key):
    return np.stack([f[key] for f in record.frames])


@pytest.mark.parametrize("mode", ["pd_joint_delta_pos", "pd_joint_pos", "pd_ee_delta_pose"])
def test_noise_perturbs_executed_actions_and_keeps_clean_labels(mode):
    record = run_episode(gym.make(LPU, control_mode=mode), ExpertPolicy(), seed=3, action_noise=1.0)
    labels, executed = _stack(record, "action"), _stack(record, "executed_action")
    arm = slice(0, labels.shape[1] - 1)
    noise = (executed - labels)[:, arm]
    unit = np.asarray(NOISE_UNITS[mode])
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
    assert gripper[record.first_success] > 0 and gripper[-1] < 0  # closed at success, open by the end
    assert _stack(record, "next.success")[record.first_success :, 0].all()


def test_settling_sets_the_peg_down_and_lets_go():
    """LiftPegUpright demonstrations otherwise end with the peg held 2 mm above the table: settling records the
    expert pressing it onto the table and opening the hand; the peg then stands by itself, its height fixed by
    the table, and stays a success."""
    env = gym.make(LPU, control_mode="pd_joint_pos")
    record = run_episode(env, ExpertPolicy(), seed=4, settle_steps=10)
    assert record.success and record.length == record.first_success + 1 + 10
    gripper = _stack(record, "action")[:, -1]
    assert gripper[record.first_success] > 0 and gripper[-1] < 0
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
    config = RecordConfig(task="LiftPegUpright-v1", episodes=2, out=out, action_noise=1.0, settle_steps=3, mcap=False)
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
        validate(RecordConfig(task="LiftPegUpright-v1", episodes=3, out=out, action_noise=1.0, resume=True))


@pytest.mark.parametrize(
    "options,needle",
    [
        ({"action_noise": -0.5}, "action_noise must be a finite number >= 0 (0: no noise), got -0.5"),
        ({"action_noise": float("nan")}, "action_noise must be a finite number >= 0 (0: no noise), got nan"),
        ({"settle_steps": -1}, "settle_steps must be an integer >= 0, got -1"),
        ({"settle_steps": 2.5}, "settle_steps must be an integer >= 0, got 2.5"),
    ],
)
def test_bad_demonstration_options_are_refused_before_anything_is_written(tmp_path, options, needle):
    out = tmp_path / "never"
    with pytest.raises(ValueError) as err:
        validate(RecordConfig(task="LiftPegUpright-v1", episodes=1, out=out, **options))
    assert str(err.value) == needle
    assert not out.exists()
