"""A robot that starts elsewhere: a table at another height, joints away from their usual start."""

from __future__ import annotations

import numpy as np
import sapien

from kitbench.perturbations.base import Perturbation
from kitbench.perturbations.registry import register_perturbation


@register_perturbation
class TableHeight(Perturbation):
    name = "table_height"
    unit = "cm"
    description = (
        "the table top `level` cm higher relative to the robot (negative: lower): the robot's base moves down by "
        "`level`; the objects, the success test and world-fixed cameras stay with the table"
    )
    minimum, maximum = -15.0, 15.0

    def robot_base(self, pose, rng):
        return sapien.Pose(np.asarray(pose.p) - [0.0, 0.0, self.level / 100.0], pose.q)


@register_perturbation
class InitialQposNoise(Perturbation):
    name = "qpos_noise"
    unit = "rad (std)"
    description = "Gaussian noise of standard deviation `level` added to each arm joint's initial position"
    minimum, maximum = 0.0, 0.5

    def initial_qpos(self, arm_qpos, rng):
        return arm_qpos + rng.normal(0.0, self.level, len(arm_qpos))
