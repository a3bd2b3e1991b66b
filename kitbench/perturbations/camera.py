"""A camera that is not where the policy was trained to expect it."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from kitbench.geometry import axis_angle_to_matrix, matrix_to_quat, quat_to_matrix
from kitbench.perturbations.base import Perturbation
from kitbench.perturbations.registry import register_perturbation


def random_direction(rng: np.random.Generator) -> np.ndarray:
    """A unit vector drawn uniformly on the sphere."""
    v = rng.standard_normal(3)
    return v / np.linalg.norm(v)


@register_perturbation
class CameraPose(Perturbation):
    name = "camera_pose"
    unit = "cm and degrees"
    description = (
        "every observation camera moved `level` cm in a random direction and turned `level` degrees about a "
        "random axis through its centre (the wrist camera relative to its mount): a calibration error"
    )
    minimum, maximum = 0.0, 30.0
    images_only = True

    def camera(self, spec, rng):
        shift = random_direction(rng) * self.level / 100.0
        turn = axis_angle_to_matrix(random_direction(rng) * math.radians(self.level))
        rotation = turn @ quat_to_matrix(spec.quaternion)
        return replace(
            spec,
            position=tuple(float(v) for v in np.asarray(spec.position) + shift),
            quaternion=tuple(float(v) for v in matrix_to_quat(rotation)),
        )
