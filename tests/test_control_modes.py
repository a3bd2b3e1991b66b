"""Each control mode is described once, on its controller class: the description is complete for every robot, says
what the controller does (absolute or delta, from the measured state or the previous target, turning or not), and
the places that read it (action names, noise, teleop, joint targets) see what it says."""

from __future__ import annotations

import functools

import gymnasium as gym
import numpy as np
import pytest

import kitbench  # noqa: F401  (registers the tasks and robots)
from kitbench.control.controllers import BASE, CONTROL_MODES, JOINTS, controller_class, make_controller, modes_where
from kitbench.control.kinematics import ArmKinematics, arm_joint_limits
from kitbench.control.noise_units import noise_std
from kitbench.envs.features import action_names
from kitbench.errors import KitbenchError
from kitbench.geometry import matrix_to_axis_angle
from kitbench.robots import ROBOTS
from kitbench.teleop.mapping import DeltaMapping, JointMapping, PhoneMapping, TurnMapping

ROBOT_UIDS = ("panda", "so101", "fetch")


def _controller(mode: str, robot: str):
    spec = ROBOTS[robot]
    limits = np.clip(arm_joint_limits(spec), -2 * np.pi, 2 * np.pi)
    controller = make_controller(mode, limits, functools.partial(ArmKinematics, spec), spec.ee_position_bound)
    controller.reset(np.array(spec.ready_arm_qpos, dtype=np.float64))
    return controller


def _offset(controller, start: np.ndarray) -> np.ndarray:
    """How far the mode's target is from `start`: joints, or the TCP's translation and rotation vector."""
    if controller.frame == JOINTS:
        return controller.joint_target - start
    target = controller.tcp_target
    return np.concatenate([target[:3, 3] - start[:3, 3], matrix_to_axis_angle(target[:3, :3] @ start[:3, :3].T)])


@pytest.mark.parametrize("robot", ROBOT_UIDS)
@pytest.mark.parametrize("mode", CONTROL_MODES)
def test_every_mode_is_described_completely_for_every_robot(mode, robot):
    cls = controller_class(mode)
    spec = ROBOTS[robot]
    controller = _controller(mode, robot)
    n_arm = controller.physical_space.shape[0] - 1
    assert cls.mode == mode and cls.frame in (JOINTS, BASE)
    assert isinstance(cls.delta, bool) and isinstance(cls.target_delta, bool) and isinstance(cls.turns, bool)
    # ManiSkill's names say it: pd_<joint|ee>_[target_][delta_]<pos|pose>
    assert cls.frame == (BASE if "_ee_" in mode else JOINTS) and cls.delta == ("delta" in mode)
    assert cls.target_delta == ("_target_delta_" in mode) and cls.turns == mode.endswith("_pose")
    assert controller.action_space.shape == controller.physical_space.shape
    names = cls.action_names(spec.units.joint_names(spec))
    assert len(names) == n_arm and len(set(names)) == n_arm, names
    if cls.frame == JOINTS:
        assert n_arm == len(spec.arm_joints) and not cls.tcp_names and not cls.turns
        assert cls.units == ("rad",) and len(cls.noise_units) == 1  # one of each, for every joint
    else:
        assert cls.units == ("m",) * 3 + ("rad",) * (3 if cls.turns else 0)
        assert len(cls.noise_units) == n_arm
    assert all(unit > 0 for unit in cls.noise_units)


@pytest.mark.parametrize("mode", CONTROL_MODES)
def test_the_description_says_what_the_controller_does(mode):
    """From the ready pose, with the arm held there: a zero action keeps a delta mode's target where it is and moves
    an absolute mode's away; the same action twice accumulates in a target-delta mode only; a turning mode's
    rotation entries turn the TCP."""
    cls = controller_class(mode)
    controller = _controller(mode, "panda")
    q0 = controller.joint_target.copy()
    n_arm = controller.physical_space.shape[0] - 1
    start = q0 if cls.frame == JOINTS else controller.kinematics.tcp_pose(q0)

    controller.arm_targets(np.zeros(n_arm), q0)
    assert np.allclose(_offset(controller, start), 0.0, atol=1e-9) == cls.delta

    controller.reset(q0)
    step = np.full(n_arm, 0.02) if cls.delta else controller.joint_action(q0 + 0.02, q0)
    controller.arm_targets(step, q0)
    first = _offset(controller, start)
    controller.arm_targets(step, q0)  # the arm has not moved
    second = _offset(controller, start)
    assert not np.allclose(first, 0.0, atol=1e-6)
    np.testing.assert_allclose(second, 2 * first if cls.target_delta else first, atol=1e-9)

    if cls.frame == BASE:
        controller.reset(q0)
        turn = np.zeros(n_arm) if cls.delta else controller.tcp_action(start, q0)
        if cls.turns:
            turn[3:6] += 0.05
        controller.arm_targets(turn, q0)
        assert np.allclose(controller.tcp_target[:3, :3], start[:3, :3], atol=1e-9) != cls.turns


@pytest.mark.parametrize("mode", CONTROL_MODES)
def test_joint_action_reaches_the_target_it_expresses(mode):
    """`joint_action` inverts `arm_targets` within the box: after a step that left a target behind, the joint
    targets it expresses are reached (end-effector modes: their TCP, through IK)."""
    controller = _controller(mode, "panda")
    q0 = controller.joint_target.copy()
    n_arm = controller.physical_space.shape[0] - 1
    controller.arm_targets(controller.joint_action(q0 + 0.03, q0), q0)  # leaves a target the arm has not reached
    wanted = q0 + np.linspace(-0.04, 0.04, len(q0))
    action = controller.joint_action(wanted, q0)
    assert action.shape == (n_arm,)
    reached = controller.arm_targets(action, q0)
    if controller.frame == JOINTS:
        np.testing.assert_allclose(reached, wanted, atol=1e-12)
        return
    got, want = controller.kinematics.tcp_pose(reached), controller.kinematics.tcp_pose(wanted)
    np.testing.assert_allclose(got[:3, 3], want[:3, 3], atol=1e-3)  # m
    if controller.turns:  # a mode without rotation entries keeps the orientation last commanded
        np.testing.assert_allclose(got[:3, :3], want[:3, :3], atol=1e-3)


@pytest.mark.parametrize("robot", ROBOT_UIDS)
def test_action_names_and_noise_fit_each_env_action(robot):
    for mode in CONTROL_MODES:
        env = gym.make("kitbench/LiftPegUpright-v1", robot_uids=robot, obs_mode="state", control_mode=mode).unwrapped
        spec = env.robot_spec
        names = action_names(env)
        assert len(names) == env.action_space.shape[0], (robot, mode)
        n_arm = len(names) - 1 - len(spec.extra_action_names)
        assert names[:n_arm] == controller_class(mode).action_names(spec.units.joint_names(spec))
        std = noise_std(env, 1.0)
        assert np.all(std[:n_arm] > 0) and not np.any(std[n_arm:]), (robot, mode)
        env.close()


def test_teleop_drives_the_modes_the_controllers_declare():
    assert DeltaMapping.modes == modes_where(lambda c: c.frame == BASE and c.delta)
    assert TurnMapping.modes == modes_where(lambda c: c.frame == BASE and c.turns)
    assert PhoneMapping.modes == modes_where(lambda c: c.frame == BASE)
    assert JointMapping.modes is None  # a leader arm's joint targets are expressed in any mode
    assert DeltaMapping.modes == (
        "pd_ee_delta_pos",
        "pd_ee_target_delta_pos",
        "pd_ee_delta_pose",
        "pd_ee_target_delta_pose",
    )
    assert TurnMapping.modes == ("pd_ee_delta_pose", "pd_ee_target_delta_pose", "pd_ee_pose")


def test_an_unknown_mode_is_refused_in_one_line():
    with pytest.raises(KitbenchError, match="pd_joint_velocity") as caught:
        controller_class("pd_joint_velocity")
    assert "\n" not in str(caught.value) and "pd_ee_pose" in str(caught.value)
