"""The size of "one unit" of action noise in each control mode, so that one noise setting means a comparable
disturbance in every mode: ~0.02 rad per arm joint. Used by demonstrations' DART noise
(`kitbench.recording.noise`) and by the `action_noise` perturbation of robustness suites."""

from __future__ import annotations

import numpy as np

JOINT_UNIT = 0.02  # rad per joint: one step of it moves the TCP ~1 cm at the Panda's reach
POSITION_UNIT = 0.01  # m, about what JOINT_UNIT does to the TCP
ROTATION_UNIT = 0.02  # rad
# Per arm entry of each mode's action (joint modes: one per arm joint, whatever their number).
NOISE_UNITS = {
    "pd_joint_delta_pos": [JOINT_UNIT],
    "pd_joint_target_delta_pos": [JOINT_UNIT],
    "pd_joint_pos": [JOINT_UNIT],
    "pd_ee_delta_pos": [POSITION_UNIT] * 3,
    "pd_ee_target_delta_pos": [POSITION_UNIT] * 3,
    "pd_ee_delta_pose": [POSITION_UNIT] * 3 + [ROTATION_UNIT] * 3,
    "pd_ee_target_delta_pose": [POSITION_UNIT] * 3 + [ROTATION_UNIT] * 3,
    "pd_ee_pose": [POSITION_UNIT] * 3 + [ROTATION_UNIT] * 3,
}


def noise_std(env, scale: float) -> np.ndarray:
    """Per-entry standard deviation of `scale` noise units on the action of `env` (a `KitbenchEnv` or the env itself):
    the arm part gets the mode's units, in the action's units (ManiSkill's normalised deltas, the SO-101's joints
    in degrees); the gripper, and a robot's body joints and base after it, get none (flipping a gripper or driving a
    base is not a small deviation to recover from)."""
    mode = env.control_mode
    n_arm = env.controller.action_space.shape[0] - 1
    units = NOISE_UNITS[mode]
    per_entry = np.asarray(units * n_arm if len(units) == 1 else units, dtype=np.float64)
    std = np.zeros(env.action_space.shape[0])
    std[:n_arm] = scale * per_entry * env.arm_action_scale()
    return std
