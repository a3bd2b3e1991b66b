"""The shared environment layer, exercised through LiftPegUpright-v1: modes, control, determinism, errors."""

from __future__ import annotations

import math
import os
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import kitbench  # noqa: F401
from kitbench.geometry import axis_angle_to_matrix, quat_to_matrix
from kitbench.sim.scene import set_actor_pose
from kitbench.tasks.lift_peg_upright import LYING_QUAT, PEG_HALF_WIDTH

TASK = "kitbench/LiftPegUpright-v1"


def make(**kw):
    return gym.make(TASK, **{"robot_init_qpos_noise": 0.0, **kw})


def _hold(env, steps):
    action = np.zeros(env.action_space.shape, dtype=np.float32)
    action[-1] = 1  # open
    if env.unwrapped.control_mode == "pd_joint_pos":
        action[:-1] = env.unwrapped.robot.qpos()[:7]
    for _ in range(steps):
        env.step(action)


# -- control modes --------------------------------------------------------------------------------
@pytest.mark.parametrize("axis", [0, 1, 2])
def test_ee_target_delta_pos_moves_tcp_by_the_commanded_amount(axis):
    env = make(control_mode="pd_ee_target_delta_pos")
    env.reset(seed=0)
    u = env.unwrapped
    start = u.robot.tcp_pose()
    action = np.zeros(4, dtype=np.float32)
    action[axis] = 0.1  # 1 cm: ManiSkill's normalised delta, 1 being 0.1 m
    action[-1] = 1
    for _ in range(10):
        env.step(action)
    _hold(env, 15)
    end = u.robot.tcp_pose()
    expected = np.zeros(3)
    expected[axis] = 0.1
    np.testing.assert_allclose(end.p - start.p, expected, atol=0.003)
    assert np.abs(quat_to_matrix(end.q) - quat_to_matrix(start.q)).max() < 0.01  # orientation kept


def test_ee_target_delta_pose_rotates_about_the_tcp():
    env = make(control_mode="pd_ee_target_delta_pose")
    env.reset(seed=0)
    u = env.unwrapped
    start = u.robot.tcp_pose()
    action = np.array([0, 0, 0, 0, 0, -0.5, 1], dtype=np.float32)  # ManiSkill scales a rotation by -0.1: 0.05 rad
    for _ in range(10):
        env.step(action)
    _hold(env, 15)
    end = u.robot.tcp_pose()
    rel = quat_to_matrix(end.q) @ quat_to_matrix(start.q).T
    assert math.atan2(rel[1, 0], rel[0, 0]) == pytest.approx(0.5, abs=0.01)
    np.testing.assert_allclose(end.p, start.p, atol=0.003)


def test_ee_pose_reaches_an_absolute_target():
    env = make(control_mode="pd_ee_pose")
    env.reset(seed=0)
    u = env.unwrapped
    # base frame: 0.5 m ahead, 0.1 m left, 0.25 m up, gripper pointing down (rotation pi about x)
    action = np.array([0.5, 0.1, 0.25, math.pi, 0, 0, 1], dtype=np.float32)
    for _ in range(25):
        env.step(action)
    tcp = u.robot.tcp_pose()
    np.testing.assert_allclose(tcp.p - u.robot.base_pose.p, [0.5, 0.1, 0.25], atol=0.003)
    assert quat_to_matrix(tcp.q)[2, 2] == pytest.approx(-1.0, abs=1e-3)


def test_joint_pos_and_joint_target_delta_pos_reach_their_targets():
    env = make(control_mode="pd_joint_pos")
    env.reset(seed=0)
    target = env.unwrapped.robot.qpos()[:7] + np.array([0.3, -0.2, 0.1, 0.2, -0.1, 0.2, 0.4])
    for _ in range(30):
        env.step(np.append(target, 1).astype(np.float32))
    np.testing.assert_allclose(env.unwrapped.robot.qpos()[:7], target, atol=0.01)

    env = make(control_mode="pd_joint_target_delta_pos")
    env.reset(seed=0)
    start = env.unwrapped.robot.qpos()[:7].copy()
    delta = np.array([0.5, 0, 0, 0, 0, 0, -0.5, 1], dtype=np.float32)  # 0.05 rad a step
    for _ in range(10):
        env.step(delta)
    _hold(env, 15)
    np.testing.assert_allclose(env.unwrapped.robot.qpos()[:7] - start, [0.5, 0, 0, 0, 0, 0, -0.5], atol=0.01)


@pytest.mark.parametrize("mode", ["pd_joint_delta_pos", "pd_ee_delta_pos", "pd_ee_delta_pose"])
def test_delta_modes_apply_the_action_to_the_measured_state(mode):
    """ManiSkill's semantics: the target is the measured state plus the action, whatever was commanded before, so
    an observation and an action always mean the same target (the `*_target_delta_*` modes accumulate)."""
    env = make(control_mode=mode)
    env.reset(seed=0)
    u = env.unwrapped
    rng = np.random.default_rng(0)
    for _ in range(6):
        q = u.robot.qpos()[:7].copy()
        action = rng.uniform(u.action_space.low, u.action_space.high).astype(np.float32)
        env.step(action)
        physical = u.action_to_sim(action)  # radians, metres, axis-angle (ManiSkill's scale and Euler read)
        if mode == "pd_joint_delta_pos":
            np.testing.assert_allclose(u.controller.joint_target, q + physical[:7], atol=1e-6)
            continue
        measured = u.controller.kinematics.tcp_pose(q)
        target = u.controller.tcp_target
        np.testing.assert_allclose(target[:3, 3], measured[:3, 3] + physical[:3], atol=1e-6)
        if mode == "pd_ee_delta_pose":
            rotated = axis_angle_to_matrix(physical[3:6]) @ measured[:3, :3]
            np.testing.assert_allclose(target[:3, :3], rotated, atol=1e-6)


@pytest.mark.parametrize("mode", ["pd_joint_delta_pos", "pd_joint_target_delta_pos"])
def test_target_delta_accumulates_where_delta_restarts_from_the_joints(mode):
    env = make(control_mode=mode)
    env.reset(seed=0)
    u = env.unwrapped
    start = u.robot.qpos()[:7].copy()
    step = np.array([1.0, 0, 0, 0, 0, 0, 0, 1], dtype=np.float32)  # 0.1 rad
    env.step(step)
    after_first = u.robot.qpos()[0]
    env.step(step)
    target = u.controller.joint_target[0]
    if mode == "pd_joint_target_delta_pos":
        assert target == pytest.approx(start[0] + 0.2, abs=1e-6)  # two steps on the previous target
    else:
        assert target == pytest.approx(after_first + 0.1, abs=1e-6)  # one step on the joint, which lags
        assert target < start[0] + 0.2 - 0.01


@pytest.mark.parametrize(
    "mode",
    ["pd_joint_pos", "pd_joint_delta_pos", "pd_joint_target_delta_pos", "pd_ee_delta_pose", "pd_ee_target_delta_pose"],
)
def test_preview_gives_the_targets_a_step_sets_and_leaves_the_controller_alone(mode):
    """`Controller.preview` (comparing a policy's action with a label, bench/open_loop.py) answers what the step
    will set, in every mode, accumulating ones included, and changes nothing the next step reads."""
    env = make(control_mode=mode)
    env.reset(seed=0)
    u = env.unwrapped
    rng = np.random.default_rng(1)
    for _ in range(4):
        action = rng.uniform(u.action_space.low, u.action_space.high).astype(np.float32)
        if mode == "pd_joint_pos":
            action[:7] = u.robot.qpos()[:7] + rng.uniform(-0.05, 0.05, 7)
        before = u.controller.joint_target.copy(), u.controller.tcp_target
        decoy = u.action_to_sim(rng.uniform(u.action_space.low, u.action_space.high))[:-1]
        decoy = u.controller.preview(decoy, u.robot.arm_qpos())
        previewed = u.controller.preview(u.action_to_sim(action)[:-1], u.robot.arm_qpos())
        np.testing.assert_array_equal(u.controller.joint_target, before[0])
        assert u.controller.tcp_target is before[1]
        assert not np.allclose(decoy, previewed)
        env.step(action)
        np.testing.assert_allclose(u.controller.joint_target, previewed, atol=1e-9)


@pytest.mark.parametrize("mode", ["pd_joint_delta_pos", "pd_ee_delta_pos", "pd_ee_delta_pose"])
def test_zero_delta_holds_the_arm_still(mode):
    env = make(control_mode=mode)
    env.reset(seed=0)
    start = env.unwrapped.robot.qpos()[:7].copy()
    _hold(env, 20)
    np.testing.assert_allclose(env.unwrapped.robot.qpos()[:7], start, atol=2e-3)


def test_gripper_opens_and_closes():
    env = make(control_mode="pd_joint_delta_pos")
    env.reset(seed=0)
    close = np.zeros(8, dtype=np.float32)
    close[-1] = -1  # ManiSkill's convention: -1 closes, +1 opens
    for _ in range(10):
        env.step(close)
    fingers = env.unwrapped.robot.qpos()[7:]
    assert np.all(fingers < 0.002) and abs(fingers[0] - fingers[1]) < 1e-3  # closed, together
    close[-1] = 1
    for _ in range(10):
        env.step(close)
    assert np.all(env.unwrapped.robot.qpos()[7:] > 0.038)


def test_out_of_box_actions_are_clipped():
    a, b = make(control_mode="pd_ee_delta_pos"), make(control_mode="pd_ee_delta_pos")
    a.reset(seed=4)
    b.reset(seed=4)
    for _ in range(5):
        oa, *_ = a.step(np.array([5.0, -5.0, 0.3, 9.0], dtype=np.float32))
        ob, *_ = b.step(np.array([1.0, -1.0, 0.3, 1.0], dtype=np.float32))
    np.testing.assert_array_equal(oa, ob)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_actions_raise(bad):
    env = make()
    env.reset(seed=0)
    action = np.zeros(8, dtype=np.float32)
    action[2] = bad
    with pytest.raises(ValueError, match="NaN or inf"):
        env.step(action)


def test_wrong_action_shape_raises():
    env = make(control_mode="pd_ee_delta_pos")
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"expects shape \(4,\)"):
        env.step(np.zeros(8, dtype=np.float32))


# -- modes and errors -----------------------------------------------------------------------------
@pytest.mark.parametrize(
    "kwargs,needle",
    [
        (
            {"obs_mode": "point_cloud"},
            (
                "unknown obs_mode 'point_cloud'; valid choices: none, state, state_dict, rgb, rgbd, depth, "
                "segmentation, rgb+depth, rgb+segmentation, depth+segmentation, rgb+depth+segmentation, pointcloud"
            ),
        ),
        ({"control_mode": "pd_joint_vel"}, "unknown control_mode 'pd_joint_vel'; valid choices: pd_joint_delta_pos"),
        (
            {"reward_mode": "shaped"},
            "unknown reward_mode 'shaped'; valid choices: dense, normalized_dense, sparse, none",
        ),
        ({"robot_uids": "ur5"}, "unknown robot_uids 'ur5'; valid choices: fetch, panda, panda_wristcam"),
        (
            {"robot_uids": "panda_wristcam"},
            "robot 'panda_wristcam' is not supported by LiftPegUprightEnv; valid choices: panda",
        ),
    ],
)
def test_bad_construction_arguments_name_value_and_choices(kwargs, needle):
    with pytest.raises(ValueError) as err:
        gym.make(TASK, **kwargs)
    assert needle in str(err.value)


def test_unknown_render_mode_raises():
    from kitbench.tasks.lift_peg_upright import LiftPegUprightEnv

    with pytest.raises(ValueError, match="unknown render_mode 'ansi'; valid choices: None, rgb_array"):
        LiftPegUprightEnv(render_mode="ansi")


def test_state_observation_layout():
    env = make(obs_mode="state_dict")
    obs, _ = env.reset(seed=2)
    assert set(obs) == {"agent", "extra"}
    assert obs["agent"]["qpos"].shape == (9,) and obs["agent"]["qvel"].shape == (9,)
    assert set(obs["extra"]) == {"tcp_pose", "peg_pose"}
    flat_env = make(obs_mode="state")
    flat, _ = flat_env.reset(seed=2)
    assert flat.dtype == np.float32 and flat.shape == (32,)
    expected = np.concatenate(
        [obs["agent"]["qpos"], obs["agent"]["qvel"], obs["extra"]["tcp_pose"], obs["extra"]["peg_pose"]]
    )
    np.testing.assert_array_equal(flat, expected)
    none_env = make(obs_mode="none")
    assert none_env.reset(seed=2)[0].shape == (0,)


def test_reward_modes():
    envs = {m: make(reward_mode=m) for m in ("dense", "normalized_dense", "sparse", "none")}
    rewards = {}
    for mode, env in envs.items():
        env.reset(seed=1)
        _, rewards[mode], *_ = env.step(np.zeros(8, dtype=np.float32))
    assert 0 < rewards["dense"] < 3
    assert rewards["normalized_dense"] == pytest.approx(rewards["dense"] / 3)
    assert rewards["sparse"] == 0.0 and rewards["none"] == 0.0
    set_actor_pose(
        envs["dense"].unwrapped.peg, [0.08, 0.08, 0.12], (math.cos(math.pi / 4), 0, -math.sin(math.pi / 4), 0)
    )
    _, r, terminated, _, info = envs["dense"].step(np.array([0, 0, 0, 0, 0, 0, 0, -1], dtype=np.float32))
    assert info["success"] and terminated and r == 3.0


def test_time_limit_truncates_after_50_steps():
    env = gym.make(TASK)
    env.reset(seed=0)
    for i in range(50):
        _, _, terminated, truncated, _ = env.step(np.zeros(8, dtype=np.float32))
        assert not terminated
        assert truncated == (i == 49)


def test_check_env_state():
    env = gym.make(TASK, obs_mode="state_dict")
    check_env(env.unwrapped, skip_render_check=True)


def test_check_env_images_and_render(needs_vulkan):
    env = gym.make(TASK, obs_mode="rgbd", render_mode="rgb_array")
    check_env(env.unwrapped)
    obs, _ = env.reset(seed=0)
    cam = obs["sensor_data"]["base_camera"]
    assert cam["rgb"].shape == (128, 128, 3) and cam["rgb"].dtype == np.uint8
    assert cam["depth"].shape == (128, 128, 1) and cam["depth"].dtype == np.float32
    params = obs["sensor_param"]["base_camera"]
    assert params["intrinsic_cv"][0, 0] == pytest.approx(64.0, rel=1e-4)  # fov pi/2 over 128 px
    # Depth is metres along the viewing axis: a pixel that sees the bare table front must read the distance at
    # which its ray, built from the reported intrinsics and extrinsics, meets the plane z = 0.
    k, ext = params["intrinsic_cv"].astype(np.float64), params["extrinsic_cv"].astype(np.float64)
    centre = -ext[:, :3].T @ ext[:, 3]
    assert centre == pytest.approx([0.3, 0, 0.6], abs=1e-5)
    for row, col in [(124, 4), (124, 64), (124, 123)]:
        ray = ext[:, :3].T @ np.linalg.solve(k, [col + 0.5, row + 0.5, 1.0])
        expected = -centre[2] / ray[2]
        assert float(cam["depth"][row, col, 0]) == pytest.approx(expected, abs=0.01)
    frame = env.render()
    assert frame.shape == (512, 512, 3) and frame.std() > 10


def test_render_without_render_mode_is_a_clear_error():
    env = make()
    env.reset(seed=0)
    with pytest.raises(RuntimeError, match="render_mode='rgb_array'"):
        env.unwrapped.render()


def test_state_only_use_runs_without_any_vulkan_device():
    code = (
        "import gymnasium as gym, numpy as np, kitbench\n"
        "env = gym.make('kitbench/LiftPegUpright-v1', obs_mode='state')\n"
        "env.reset(seed=0)\n"
        "for _ in range(5): env.step(env.action_space.sample())\n"
        "env.close(); print('state-only ok')\n"
    )
    env = {**os.environ, "VK_ICD_FILENAMES": "/nonexistent", "VK_DRIVER_FILES": "/nonexistent"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "state-only ok" in out.stdout


# -- determinism ----------------------------------------------------------------------------------
def _contact_rollout(env, seed, descend=8):
    """Reset, put the peg under the gripper, descend, grasp and lift: a rollout full of contacts."""
    obs, _ = env.reset(seed=seed)
    u = env.unwrapped
    tcp = u.robot.tcp_pose().p
    set_actor_pose(u.peg, [tcp[0], tcp[1], PEG_HALF_WIDTH], LYING_QUAT)
    rng = np.random.default_rng(seed)
    frames = [obs]
    # ManiSkill's normalised deltas (0.3: 3 cm a step) and gripper (+1 open, -1 closed)
    plan = [[0, 0, -0.3, 1]] * descend + [[0, 0, 0, -1]] * 5 + [[0, 0, 0.3, -1]] * 8
    for a in plan:
        noisy = np.asarray(a, dtype=np.float32) + rng.normal(0, 0.02, 4).astype(np.float32)
        obs, *_ = env.step(noisy)
        frames.append(obs)
    return np.stack(frames)


def test_same_seed_same_actions_bitwise_identical():
    a = make(control_mode="pd_ee_delta_pos", robot_init_qpos_noise=0.02)
    first = _contact_rollout(a, 11)
    assert first[-1][-7 + 2] > 0.05, "the rollout should have lifted the peg"
    _contact_rollout(a, 12, descend=11)  # a different episode in between, pressing into the table
    again = _contact_rollout(a, 11)
    fresh = _contact_rollout(make(control_mode="pd_ee_delta_pos", robot_init_qpos_noise=0.02), 11)
    np.testing.assert_array_equal(first, again)
    np.testing.assert_array_equal(first, fresh)


def test_different_seeds_differ():
    env = make(robot_init_qpos_noise=0.02)
    a, _ = env.reset(seed=1)
    b, _ = env.reset(seed=2)
    assert not np.array_equal(a, b)


def test_close_frees_the_scene():
    env = make()
    env.reset(seed=0)
    env.close()
    assert env.unwrapped.scene is None
