"""The size of "one unit" of action noise in each control mode, so that one noise setting means a comparable
disturbance in every mode: ~0.02 rad per arm joint. Used by demonstrations' DART noise
(`kitbench.recording.noise`) and by the `action_noise` perturbation of robustness suites."""

from __future__ import annotations

import numpy as np

JOINT_UNIT = 0.02  # rad per joint: one step of it moves the TCP ~1 cm at the Panda's reach
POSITION_UNIT = 0.01  # m, about what JOINT_UNIT does to the TCP
ROTATION_UNIT = 0.02  # rad
NOISE_UNITS = {
    "pd_joint_delta_pos": [JOINT_UNIT] * 7,
    "pd_joint_target_delta_pos": [JOINT_UNIT] * 7,
    "pd_joint_pos": [JOINT_UNIT] * 7,
    "pd_ee_delta_pos": [POSITION_UNIT] * 3,
    "pd_ee_target_delta_pos": [POSITION_UNIT] * 3,
    "pd_ee_delta_pose": [POSITION_UNIT] * 3 + [ROTATION_UNIT] * 3,
    "pd_ee_target_delta_pose": [POSITION_UNIT] * 3 + [ROTATION_UNIT] * 3,
    "pd_ee_pose": [POSITION_UNIT] * 3 + [ROTATION_UNIT] * 3,
}


def noise_std(control_mode: str, scale: float, action_size: int) -> np.ndarray:
    """Per-entry standard deviation of `scale` noise units on an action of `action_size` entries: the arm part
    gets the mode's units; the gripper, and a robot's body joints and base after it, get none (flipping a gripper
    or driving a base is not a small deviation to recover from)."""
    units = np.asarray(NOISE_UNITS[control_mode], dtype=np.float64)
    std = np.zeros(action_size)
    std[: len(units)] = scale * units
    return std
