"""Action noise for demonstrations that teach recovery (DART, Laskey et al. 2017).

The robot executes the policy's action plus seeded Gaussian noise; the dataset keeps the policy's own action as
the label. The expert is closed loop (each action is planned from the simulated state, and a phase is re-planned
from wherever the previous one ended), so the labels show how to get back on track from states a noise-free
expert never visits: the states a learned policy drifts into.

`scale` is a multiple of the control mode's noise unit (`Controller.noise_units`), so one setting means a comparable
disturbance in every mode: ~0.02 rad per arm joint. The gripper gets no noise: flipping it is not a small
deviation to recover from but a different action.
"""

from __future__ import annotations

import math

import numpy as np

from kitbench.control.noise_units import noise_std
from kitbench.envs.interface import KitbenchEnv
from kitbench.errors import KitbenchError

_STREAM = 0xDA27  # keeps the noise stream apart from the env's own use of the seed


def check_noise_scale(scale) -> None:
    if not (isinstance(scale, int | float) and not isinstance(scale, bool) and 0 <= scale < math.inf):
        raise KitbenchError(f"action_noise must be a finite number >= 0 (0: no noise), got {scale!r}")


class ActionNoise:
    """Per-episode noise for one control mode: `perturb(action)` returns the action to execute."""

    def __init__(self, std: np.ndarray, seed: int, low: np.ndarray, high: np.ndarray):
        self.std = std
        self.low, self.high = low, high
        self.rng = np.random.default_rng([seed, _STREAM])

    @classmethod
    def for_env(cls, env: KitbenchEnv, scale: float, seed: int) -> ActionNoise:
        check_noise_scale(scale)
        return cls(noise_std(env, scale), seed, env.action_space.low, env.action_space.high)

    def perturb(self, action: np.ndarray) -> np.ndarray:
        noisy = action + self.rng.standard_normal(action.shape) * self.std
        return np.clip(noisy, self.low, self.high).astype(np.float32)


__all__ = ["ActionNoise", "check_noise_scale"]
