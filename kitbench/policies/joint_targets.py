"""Express a joint-position target in any control mode, so a planner written for one mode drives them all.

A delta is taken from what the mode applies it to (`Controller.joint_action`): the measured joints or TCP
(`pd_*_delta_*`), or the controller's previous target (`pd_*_target_delta_*`). The action then reproduces the
planner's target exactly whenever it fits in the mode's action box (delta modes clip larger steps; the closed-loop
planner then adapts).
"""

from __future__ import annotations

import numpy as np

from kitbench.envs.interface import as_kitbench


def joint_target_to_action(env, arm_target: np.ndarray, gripper: float, clip: bool = True) -> np.ndarray:
    """The env's action (in the robot's units) that drives the arm to `arm_target` (joint positions, radians) with
    the gripper at `gripper` (a command, -1 closed .. 1 open), clipped to the action box unless `clip` is False
    (then it says how far outside the box the target lies)."""
    u = as_kitbench(env)
    arm = u.controller.joint_action(arm_target, u.robot.arm_qpos())
    # the robot's body joints and base (if any) hold still: zero deltas, zero velocities
    extra = np.zeros(len(u.robot_spec.extra_action_names))
    action = u.action_from_sim(np.concatenate([arm, [gripper], extra]).astype(np.float32))
    if not clip:
        return action
    space = u.action_space
    return np.clip(action, space.low, space.high)
