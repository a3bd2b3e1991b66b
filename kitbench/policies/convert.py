"""Express a joint-position target in any control mode, so a planner written for one mode drives them all.

The conversion reads the controller's own targets, so the action reproduces the planner's intent exactly
whenever it fits in the mode's action box (delta modes clip larger steps; the closed-loop planner then adapts).
"""

from __future__ import annotations

import numpy as np

from kitbench.control.controllers import pose_to_ee_action
from kitbench.geometry import matrix_to_axis_angle


def joint_target_to_action(env, arm_target: np.ndarray, gripper: float) -> np.ndarray:
    u = env.unwrapped
    mode = u.control_mode
    controller = u.controller
    if mode == "pd_joint_pos":
        arm = arm_target
    elif mode == "pd_joint_delta_pos":
        arm = arm_target - controller.joint_target
    else:
        kin = controller.kinematics
        target = kin.tcp_pose(arm_target)
        if mode == "pd_ee_pose":
            arm = pose_to_ee_action(target)
        else:
            previous = controller.tcp_target
            if previous is None:
                previous = kin.tcp_pose(u.robot.qpos()[:7])
            arm = target[:3, 3] - previous[:3, 3]
            if mode == "pd_ee_delta_pose":
                arm = np.concatenate([arm, matrix_to_axis_angle(target[:3, :3] @ previous[:3, :3].T)])
    action = np.append(arm, gripper).astype(np.float32)
    space = u.action_space
    return np.clip(action, space.low, space.high)
