"""Fetch on LiftPegUpright-v1: a first-class robot. The env passes gymnasium's checks; every part of the action
(arm in each control mode, gripper, head and torso, base) moves what it says; a zero action holds the base;
episodes are deterministic; observations carry every joint, the TCP and the base; images come from Fetch's
cameras; recordings and policies know their robot."""

from __future__ import annotations

import json
import math

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import kitbench  # noqa: F401  (registers the tasks)
from kitbench.control.controllers import axis_angle_to_euler
from kitbench.envs.features import action_names
from kitbench.errors import KitbenchError
from kitbench.geometry import matrix_to_axis_angle, pose_to_matrix

LPU = "kitbench/LiftPegUpright-v1"


def _env(control_mode: str = "pd_joint_delta_pos", **kwargs):
    return gym.make(LPU, robot_uids="fetch", control_mode=control_mode, **kwargs)


def _tcp(u) -> np.ndarray:
    p = u.robot.tcp_pose()
    return pose_to_matrix(p.p, p.q)


def _zero(env) -> np.ndarray:
    return np.zeros(env.action_space.shape, dtype=np.float32)


def test_check_env_state():
    env = _env()
    check_env(env.unwrapped, skip_render_check=True)


def test_the_action_layout_is_arm_gripper_body_base():
    env = _env("pd_joint_pos")
    names = action_names(env)
    assert len(names) == env.action_space.shape[0] == 13
    assert names[:7] == [
        "shoulder_pan_joint",
        "shoulder_lift_joint",
        "upperarm_roll_joint",
        "elbow_flex_joint",
        "forearm_roll_joint",
        "wrist_flex_joint",
        "wrist_roll_joint",
    ]
    assert names[7:] == [
        "gripper",
        "delta_head_pan_joint",
        "delta_head_tilt_joint",
        "delta_torso_lift_joint",
        "base_forward_velocity",
        "base_yaw_rate",
    ]
    assert action_names(_env("pd_ee_delta_pose"))[:7] == ["dx", "dy", "dz", "drx", "dry", "drz", "gripper"]


def test_observations_carry_every_joint_the_tcp_and_the_base():
    env = _env(obs_mode="state_dict")
    obs, _ = env.reset(seed=0)
    u = env.unwrapped
    assert obs["agent"]["qpos"].shape == (15,) and obs["agent"]["qvel"].shape == (15,)
    np.testing.assert_allclose(obs["extra"]["base_pose"][:3], [-1.05, 0.0, -0.92], atol=1e-6)
    assert u.robot_state_names[-3:] == ("base_x", "base_y", "base_yaw")
    assert u.robot_state().shape == (14,)
    # the gripper opening is the sum of the two finger joints: open, 2 x 5 cm
    assert u.robot_state()[7] == pytest.approx(0.1, abs=1e-6)


def test_zero_action_holds_the_base_and_the_arm_for_200_steps():
    for mode in ("pd_joint_delta_pos", "pd_ee_delta_pose"):
        env = _env(mode)
        env.reset(seed=0)
        u = env.unwrapped
        base, tcp = u.robot.base_pose.p.copy(), _tcp(u)
        for _ in range(200):
            env.step(_zero(env))
        assert np.linalg.norm(u.robot.base_pose.p - base) < 1e-3, mode
        assert np.linalg.norm(_tcp(u)[:3, 3] - tcp[:3, 3]) < 1e-3, mode


def test_joint_modes_move_the_arm_joints_by_the_action():
    """Target deltas accumulate (four steps of 0.05 rad: 0.2 rad once the drives settle); absolute targets are
    reached."""
    env = _env("pd_joint_target_delta_pos")
    env.reset(seed=0)
    u = env.unwrapped
    start = u.robot.arm_qpos().copy()
    action = _zero(env)
    action[:7] = [0.5, 0.5, 0.5, 0.5, -0.5, -0.5, 0.5]  # 0.05 rad a step (1 is 0.1); inside the joint limits
    for _ in range(4):
        env.step(action)
    for _ in range(6):
        env.step(_zero(env))
    np.testing.assert_allclose(u.robot.arm_qpos() - start, 4 * 0.1 * action[:7], atol=0.01)
    env = _env("pd_joint_pos")
    env.reset(seed=0)
    u = env.unwrapped
    target = u.robot.arm_qpos() + [0.2, 0.1, -0.2, -0.1, 0.2, -0.2, 0.3]
    action = _zero(env)
    action[:7] = target
    for _ in range(15):
        env.step(action)
    np.testing.assert_allclose(u.robot.arm_qpos(), target, atol=0.01)


def test_end_effector_delta_moves_the_tcp_in_the_base_frame():
    """Accumulated TCP deltas (three 2 cm steps: 6 cm once the arm settles), orientation kept."""
    env = _env("pd_ee_target_delta_pos")
    env.reset(seed=0)
    u = env.unwrapped
    start = _tcp(u)
    action = _zero(env)
    action[:3] = [0.2, 0.0, -0.2]  # forward and down, 2 cm a step (1 is 0.1 m)
    for _ in range(3):
        env.step(action)
    for _ in range(6):
        env.step(_zero(env))
    moved = _tcp(u)[:3, 3] - start[:3, 3]  # the base frame is the world's, turned by nothing
    np.testing.assert_allclose(moved, [0.06, 0.0, -0.06], atol=0.005)
    assert math.degrees(np.linalg.norm(matrix_to_axis_angle(_tcp(u)[:3, :3] @ start[:3, :3].T))) < 1.0


def test_end_effector_pose_reaches_the_commanded_pose():
    env = _env("pd_ee_pose")
    env.reset(seed=0)
    u = env.unwrapped
    base = pose_to_matrix(u.robot.base_pose.p, u.robot.base_pose.q)
    target = np.linalg.inv(base) @ _tcp(u)
    target[:3, 3] += [0.05, 0.05, -0.05]  # (up, the wrist would reach its flex limit first)
    action = _zero(env)
    action[:3] = target[:3, 3]
    action[3:6] = axis_angle_to_euler(matrix_to_axis_angle(target[:3, :3]))  # ManiSkill's XYZ Euler
    for _ in range(15):
        env.step(action)
    np.testing.assert_allclose((np.linalg.inv(base) @ _tcp(u))[:3, 3], target[:3, 3], atol=0.005)


def test_body_actions_move_head_and_torso():
    env = _env()
    env.reset(seed=0)
    u = env.unwrapped
    start = u.robot.body_qpos().copy()  # head pan, head tilt, torso
    action = _zero(env)
    action[8:11] = [1.0, -1.0, -0.5]  # 0.1 rad, -0.1 rad, -0.05 m a step (ManiSkill's normalised body deltas)
    for _ in range(3):
        env.step(action)
    for _ in range(40):  # ManiSkill's body drives (1e3, 1e2, 100 N) bring the heavy torso in slowly
        env.step(_zero(env))
    np.testing.assert_allclose(u.robot.body_qpos() - start, [0.3, -0.3, -0.15], atol=0.01)


def test_base_actions_drive_forward_and_turn():
    env = _env()
    env.reset(seed=0)
    u = env.unwrapped
    action = _zero(env)
    action[11] = 0.2  # m/s for 10 steps of 50 ms: 10 cm
    for _ in range(10):
        env.step(action)
    for _ in range(10):
        env.step(_zero(env))
    x, y, yaw = u.robot.base_state()
    assert x == pytest.approx(0.10, abs=0.005) and abs(y) < 1e-3 and abs(yaw) < 1e-3
    action[11], action[12] = 0.0, 0.5 / 3.14  # 0.5 rad/s (1 is 3.14) for 10 steps: 0.25 rad
    for _ in range(10):
        env.step(action)
    for _ in range(10):
        env.step(_zero(env))
    assert u.robot.base_state()[2] == pytest.approx(0.25, abs=0.01)
    # the arm's frame moved with the base: its TCP pose in the base frame did not change
    assert u.robot.base_pose.p[0] == pytest.approx(-1.05 + 0.10, abs=0.005)


def test_fetch_episodes_are_deterministic():
    def run():
        env = _env()
        rng = np.random.default_rng(3)
        obs, _ = env.reset(seed=11)
        out = [obs]
        for _ in range(10):
            a = env.action_space.low + rng.random(13) * (env.action_space.high - env.action_space.low)
            out.append(env.step(a.astype(np.float32))[0])
        return np.array(out)

    np.testing.assert_array_equal(run(), run())


def test_fetch_is_refused_by_a_task_that_does_not_support_it():
    with pytest.raises(KitbenchError, match=r"robot 'fetch' is not supported by AssemblingKitsEnv; valid choices: "):
        gym.make("kitbench/AssemblingKits-v1", robot_uids="fetch")
    with pytest.raises(
        KitbenchError, match=r"unknown robot_uids 'fetchh'; valid choices: fetch, panda, panda_wristcam"
    ):
        gym.make(LPU, robot_uids="fetchh")


@pytest.mark.render
def test_fetch_cameras_see_the_scene_and_the_hand_camera_moves_with_the_gripper():
    env = _env(obs_mode="rgb")
    obs, _ = env.reset(seed=0)
    assert set(obs["sensor_data"]) == {"base_camera", "fetch_head", "fetch_hand"}
    for name in ("fetch_head", "fetch_hand"):
        image = obs["sensor_data"][name]["rgb"]
        assert image.shape == (128, 128, 3) and image.std() > 5
    before = obs["sensor_param"]["fetch_hand"]["cam2world_gl"].copy()
    action = _zero(env)
    action[0] = 1.0  # 0.1 rad a step
    for _ in range(3):
        obs, *_ = env.step(action)
    after = obs["sensor_param"]["fetch_hand"]["cam2world_gl"]
    assert np.linalg.norm(after[:3, 3] - before[:3, 3]) > 0.02


# -- recording, evaluation, policies --------------------------------------------------------------------
def test_a_fetch_recording_round_trips_through_stock_lerobot(tmp_path):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from mcap.reader import make_reader

    from kitbench.metadata import read_recording_settings
    from kitbench.recording.config import RecordConfig
    from kitbench.recording.recorder import record

    out = tmp_path / "fetch"
    record(
        RecordConfig.of(task="LiftPegUpright-v1", episodes=2, out=out, policy="random", robot="fetch"), progress=False
    )
    dataset = LeRobotDataset("kitbench/LiftPegUpright-v1", root=out)
    assert dataset.meta.robot_type == "fetch"
    assert dataset.meta.features["observation.state"]["names"][-3:] == ["base_x", "base_y", "base_yaw"]
    assert dataset.meta.features["action"]["shape"] == (13,)
    frame = dataset[0]
    assert frame["observation.state"].shape == (14,) and frame["action"].shape == (13,)
    assert read_recording_settings(out)["robot"] == "fetch"
    with open(out / "mcap" / "episode_000000.mcap", "rb") as f:
        topics = {channel.topic for _, channel, _ in make_reader(f).iter_messages()}
    assert {"/tf", "/joint_states", "/scene"} <= topics
    with pytest.raises(KitbenchError, match=r"cannot resume .*\(robot: recorded 'fetch', asked None\)"):
        record(RecordConfig.of(task="LiftPegUpright-v1", episodes=3, out=out, policy="random", resume=True))


class _TrainedOn:
    """A stand-in for a lerobot checkpoint's requirements."""

    name = "lerobot:ckpt"

    def __init__(self, robot):
        self.robot = robot

    def requirements(self):
        return {"robot": self.robot, "control_mode": "pd_joint_delta_pos"}


def test_a_policy_trained_on_one_robot_runs_on_it_and_is_refused_on_the_other():
    from kitbench.evaluation.config import COMMAND_LINE
    from kitbench.evaluation.runner import fit_suite_to_policy
    from kitbench.evaluation.suite import adhoc_suite

    suite = adhoc_suite("LiftPegUpright-v1", 2)
    assert fit_suite_to_policy(suite, _TrainedOn("fetch"), {}).robot_uid == "fetch"
    panda = adhoc_suite("LiftPegUpright-v1", 2, robot="panda")
    with pytest.raises(KitbenchError, match=r"trained on robot fetch but this evaluation runs panda; .*--robot fetch"):
        fit_suite_to_policy(panda, _TrainedOn("fetch"), {"robot": COMMAND_LINE})
    with pytest.raises(KitbenchError, match=r"robot 'fetch' is not supported by AssemblingKits-v1"):
        adhoc_suite("AssemblingKits-v1", 2, robot="fetch")


def test_the_dataset_card_names_the_joints_a_fetch_expert_holds_still(tmp_path):
    """Fetch's expert drives only the arm: its head and base sit still up to servo jitter, which LeRobot's
    mean/std normalisation would blow up. The card says which entries those are, and no arm joint among them (the
    torso gives a little under the arm on ManiSkill's body drives, so it is not among them)."""
    from kitbench.recording.config import RecordConfig
    from kitbench.recording.recorder import record

    out = tmp_path / "fetch"
    config = RecordConfig.of(
        task="LiftPegUpright-v1", episodes=2, out=out, control_mode="pd_joint_pos", robot="fetch", mcap=False
    )
    record(config, progress=False)
    held = [
        line
        for line in (out / "README.md").read_text().splitlines()
        if line.startswith("- Held still: `observation.state`")
    ]
    assert len(held) == 1, held
    body = ["head_pan_joint", "head_tilt_joint", "base_x", "base_y", "base_yaw"]
    assert all(f"`{name}`" in held[0] for name in body), held[0]
    arm = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_flex_joint", "wrist_roll_joint", "gripper_opening"]
    assert not any(f"`{name}`" in held[0] for name in arm), held[0]


def test_still_entries_reads_the_state_std_against_the_threshold(tmp_path):
    from kitbench.recording.card import STILL_STD, still_entries

    (tmp_path / "meta").mkdir()
    names = ["a", "b", "c"]
    info = {"features": {"observation.state": {"names": names, "shape": [3]}}}
    assert still_entries(tmp_path, info) == {}  # no stats yet: nothing claimed
    stats = {"observation.state": {"std": [0.2, STILL_STD / 2, STILL_STD]}}
    (tmp_path / "meta" / "stats.json").write_text(json.dumps(stats))
    assert still_entries(tmp_path, info) == {"observation.state": ["b"]}
    # the environment state is read the same way, on its own names and stats (a task constant: std 7e-6)
    info["features"]["observation.environment_state"] = {"names": ["goal.x", "goal.z"], "shape": [2]}
    stats["observation.environment_state"] = {"std": [0.05, 7e-6]}
    (tmp_path / "meta" / "stats.json").write_text(json.dumps(stats))
    assert still_entries(tmp_path, info) == {"observation.state": ["b"], "observation.environment_state": ["goal.z"]}
    stats["observation.state"]["std"] = [0.2, 0.3, 0.4]  # a vector with nothing held still is left out
    (tmp_path / "meta" / "stats.json").write_text(json.dumps(stats))
    assert still_entries(tmp_path, info) == {"observation.environment_state": ["goal.z"]}
