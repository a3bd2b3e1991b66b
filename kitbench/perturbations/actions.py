"""Actions that do not arrive as sent: late, or noisy."""

from __future__ import annotations

from collections import deque

import numpy as np

from kitbench.control.noise_units import noise_std
from kitbench.perturbations.base import Perturbation
from kitbench.perturbations.registry import register_perturbation


@register_perturbation
class ActionDelay(Perturbation):
    name = "action_delay"
    unit = "steps"
    description = (
        "each action executed `level` control steps after it was chosen; for the first `level` steps the robot "
        "holds its initial joint and gripper targets"
    )
    minimum, maximum = 0, 20
    integer = True

    def start_episode(self, rng):
        self._queue: deque = deque()

    def action(self, action, env, rng):
        self._queue.append(action)
        return self._queue.popleft() if len(self._queue) > self.level else None


@register_perturbation
class ActionNoise(Perturbation):
    name = "action_noise"
    unit = "noise units"
    description = (
        "Gaussian noise of `level` noise units added to every arm action (a unit is ~0.02 rad a joint, 1 cm, "
        "0.02 rad, as `kitbench record --action-noise`); the gripper action is left alone"
    )
    minimum, maximum = 0.0, 10.0

    def action(self, action, env, rng):
        if action is None:
            return None
        std = noise_std(env, self.level)
        noisy = action + rng.standard_normal(action.shape) * std
        return np.clip(noisy, env.action_space.low, env.action_space.high).astype(np.float32)
