"""Perturbations: documented, seeded changes to a task's env that robustness suites score policies under.

`gym.make("kitbench/LiftPegUpright-v1", perturbations={"camera_pose": 2.0, "action_delay": 1})` runs the task
under both. Each is one class in this package (one concept a file, in the order they are applied), registered by
name with its unit, its valid levels and what a level does (`PERTURBATIONS`, `describe()`), and each draws from
a stream of its own derived from the episode's seed: a perturbed episode is deterministic in its seed and starts
from the nominal episode's object placement.
"""

from __future__ import annotations

from kitbench.perturbations import actions, camera, lighting, objects, observations, robot  # noqa: F401 (register)
from kitbench.perturbations.applied import Perturbations
from kitbench.perturbations.base import Perturbation
from kitbench.perturbations.registry import PERTURBATIONS, make_perturbation, register_perturbation


def describe() -> list[tuple[str, str, str]]:
    """(name, unit, what a level does) for every perturbation, in the order they are applied."""
    return [(cls.name, cls.unit, cls.description) for cls in PERTURBATIONS.values()]


__all__ = ["PERTURBATIONS", "Perturbation", "Perturbations", "describe", "make_perturbation", "register_perturbation"]
