"""The size of "one unit" of action noise in each control mode, so that one noise setting means a comparable
disturbance in every mode: ~0.02 rad per arm joint. Each controller class gives its arm entries' units
(`Controller.noise_units`). Used by demonstrations' DART noise (`kitbench.recording.noise`) and by the
`action_noise` perturbation of robustness suites."""

from __future__ import annotations

import numpy as np

JOINT_UNIT = 0.02  # rad per joint: one step of it moves the TCP ~1 cm at the Panda's reach
POSITION_UNIT = 0.01  # m, about what JOINT_UNIT does to the TCP
ROTATION_UNIT = 0.02  # rad


def noise_std(env, scale: float) -> np.ndarray:
    """Per-entry standard deviation of `scale` noise units on the action of `env` (a `KitbenchEnv` or the env itself):
    the arm part gets the mode's units, in the action's units (ManiSkill's normalised deltas, the SO-101's joints
    in degrees); the gripper, and a robot's body joints and base after it, get none (flipping a gripper or driving a
    base is not a small deviation to recover from)."""
    controller = env.controller
    n_arm = controller.action_space.shape[0] - 1
    # a joint mode gives one unit for every joint
    per_entry = np.broadcast_to(np.asarray(controller.noise_units, dtype=np.float64), n_arm)
    std = np.zeros(env.action_space.shape[0])
    std[:n_arm] = scale * per_entry * env.arm_action_scale()
    return std
