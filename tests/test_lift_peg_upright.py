"""LiftPegUpright-v1: success predicate on constructed poses and physics outcomes."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

import kitbench  # noqa: F401  (registers the tasks)
from kitbench.geometry import axis_quat, matrix_to_quat, quat_to_matrix
from kitbench.sim.scene import set_actor_pose
from kitbench.tasks.lift_peg_upright import PEG_HALF_LENGTH, PEG_HALF_WIDTH, peg_success
from tests.scripted import WaypointFollower


def _peg_quat_with_axis(axis, yaw: float = 0.0) -> np.ndarray:
    """A quaternion whose body x axis points along `axis`, then spun by `yaw` about that axis."""
    x = np.asarray(axis, float) / np.linalg.norm(axis)
    helper = np.array([0, 0, 1.0]) if abs(x[2]) < 0.9 else np.array([1.0, 0, 0])
    y = np.cross(helper, x)
    y /= np.linalg.norm(y)
    z = np.cross(x, y)
    spin = quat_to_matrix(axis_quat(x, yaw))
    return matrix_to_quat(spin @ np.stack([x, y, z], axis=1))


def _tilted(tilt: float, azimuth: float = 0.3) -> np.ndarray:
    return _peg_quat_with_axis([math.sin(tilt) * math.cos(azimuth), math.sin(tilt) * math.sin(azimuth), math.cos(tilt)])


@pytest.mark.parametrize("up", [1.0, -1.0])
def test_upright_either_end_up_succeeds(up):
    ok, tilt, _ = peg_success([0, 0, PEG_HALF_LENGTH], _peg_quat_with_axis([0, 0, up]))
    assert ok and tilt < 1e-6


@pytest.mark.parametrize("tilt,expected", [(0.07, True), (0.09, False)])
def test_tilt_threshold(tilt, expected):
    ok, measured, _ = peg_success([0, 0, PEG_HALF_LENGTH], _tilted(tilt))
    assert ok is expected
    assert measured == pytest.approx(tilt, abs=1e-6)


@pytest.mark.parametrize("dz,expected", [(0.004, True), (-0.004, True), (0.006, False), (-0.006, False)])
def test_height_threshold(dz, expected):
    assert peg_success([0.05, -0.02, PEG_HALF_LENGTH + dz], _tilted(0.01))[0] is expected


@pytest.mark.parametrize("roll", [0.0, math.pi / 2, math.pi, -math.pi / 2])
def test_horizontal_peg_at_upright_height_fails(roll):
    # The reference implementation's Euler check accepts exactly this pose.
    q = _peg_quat_with_axis([1.0, 0, 0], roll)
    assert not peg_success([0, 0, PEG_HALF_LENGTH], q)[0]


@pytest.mark.parametrize("yaw", np.linspace(0, 2 * math.pi, 9))
def test_invariant_to_yaw(yaw):
    upright = _peg_quat_with_axis([0, 0, 1], yaw)
    tilted = _tilted(0.05, azimuth=yaw)
    too_tilted = _tilted(0.1, azimuth=yaw)
    assert peg_success([0, 0, PEG_HALF_LENGTH], upright)[0]
    assert peg_success([0, 0, PEG_HALF_LENGTH], tilted)[0]
    assert not peg_success([0, 0, PEG_HALF_LENGTH], too_tilted)[0]


def test_env_reports_success_fields_on_teleported_peg():
    env = gym.make("kitbench/LiftPegUpright-v1")
    env.reset(seed=0)
    peg = env.unwrapped.peg
    set_actor_pose(peg, [0.0, 0.0, PEG_HALF_LENGTH], _peg_quat_with_axis([0, 0, -1], 1.0))
    info = env.unwrapped.evaluate()
    assert info["success"] and info["tilt"] < 1e-5 and info["z_error"] < 1e-6
    set_actor_pose(peg, [0.0, 0.0, PEG_HALF_LENGTH], _peg_quat_with_axis([1, 0, 0]))
    assert not env.unwrapped.evaluate()["success"]


def test_initial_peg_lies_flat_in_the_spawn_region():
    env = gym.make("kitbench/LiftPegUpright-v1", obs_mode="state_dict")
    for seed in range(20):
        obs, info = env.reset(seed=seed)
        p = obs["extra"]["peg_pose"]
        assert np.all(np.abs(p[:2]) <= 0.1)
        assert p[2] == pytest.approx(PEG_HALF_WIDTH, abs=1e-6)
        assert info["tilt"] == pytest.approx(math.pi / 2, abs=1e-5)
        assert not info["success"]


def test_upright_peg_stays_upright_and_successful_for_50_steps():
    env = gym.make("kitbench/LiftPegUpright-v1", obs_mode="state", reward_mode="sparse")
    env.reset(seed=3)
    set_actor_pose(env.unwrapped.peg, [0.05, 0.05, PEG_HALF_LENGTH], _peg_quat_with_axis([0, 0, 1], 0.4))
    zero = np.zeros(env.action_space.shape, dtype=np.float32)
    zero[-1] = -1
    for _ in range(50):
        _, reward, terminated, _, info = env.unwrapped.step(zero)
        assert info["success"] and terminated and reward == 1.0
    assert info["tilt"] < 0.01


def test_grasped_peg_is_lifted_and_rotated_without_slipping():
    env = gym.make("kitbench/LiftPegUpright-v1", control_mode="pd_joint_pos", robot_init_qpos_noise=0.0)
    env.reset(seed=1)
    u = env.unwrapped
    follow = WaypointFollower(env)
    peg_p = u.peg.pose.p.copy()
    grasp = follow.tcp_world()
    grasp[:3, 3] = [peg_p[0] + 0.03, peg_p[1], PEG_HALF_WIDTH]  # 3 cm off-centre along the peg
    above = grasp.copy()
    above[2, 3] += 0.1
    follow.move(above, 1, 15)  # ManiSkill's gripper: +1 open, -1 closed
    follow.move(grasp, 1, 10)
    follow.move(grasp, -1, 1, settle=8)
    assert u.robot.is_grasping(u.peg)
    lifted = grasp.copy()
    lifted[2, 3] += 0.1
    follow.move(lifted, -1, 15)
    tcp = follow.tcp_world()
    assert u.peg.pose.p[2] == pytest.approx(PEG_HALF_WIDTH + 0.1, abs=0.01)
    offset_before = np.linalg.inv(tcp) @ np.append(u.peg.pose.p, 1)
    # +90 degrees about world y, moving towards the robot where the arm can point the hand back at it: the
    # peg's long axis (the hand's x axis) swings from horizontal to vertical.
    turned = lifted.copy()
    turned[:3, :3] = np.array([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]]) @ lifted[:3, :3]
    turned[:3, 3] = [-0.17, lifted[1, 3], 0.2]
    follow.move(turned, -1, 25, settle=10)
    tcp = follow.tcp_world()
    offset_after = np.linalg.inv(tcp) @ np.append(u.peg.pose.p, 1)
    axis = quat_to_matrix(u.peg.pose.q)[:, 0]
    in_hand = tcp[:3, :3].T @ axis  # the peg's axis in the TCP frame: (1, 0, 0) before the motion
    assert abs(axis[2]) > math.cos(math.radians(2)), f"peg not vertical: axis {axis}"
    assert math.degrees(math.acos(min(1.0, abs(in_hand[0])))) < 1.0, f"peg turned in the grasp: {in_hand}"
    assert np.linalg.norm(offset_after[:3] - offset_before[:3]) < 0.002, "peg slipped in the grasp"
    assert u.robot.is_grasping(u.peg)
