"""A state observation measured with noise."""

from __future__ import annotations

import numpy as np

from kitbench.perturbations.base import Perturbation
from kitbench.perturbations.registry import register_perturbation


def _noisy(tree, level: float, rng: np.random.Generator):
    """`tree` (nested dicts of arrays) with Gaussian noise on every entry, drawn in key order."""
    if isinstance(tree, dict):
        return {k: _noisy(v, level, rng) for k, v in tree.items()}
    values = np.asarray(tree)
    return (values + rng.normal(0.0, level, values.shape)).astype(values.dtype)


@register_perturbation
class ObservationNoise(Perturbation):
    name = "obs_noise"
    unit = "std (m, rad)"
    description = (
        "Gaussian noise of standard deviation `level` on every entry of the state observation (joint positions "
        "and velocities, the TCP pose, the task's object and goal fields), fresh each step; images are not "
        "touched, and the scripted experts, which plan from the simulator, do not see it"
    )
    minimum, maximum = 0.0, 1.0

    def observation(self, state, rng):
        return _noisy(state, self.level, rng)
