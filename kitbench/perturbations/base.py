"""One perturbation: a documented, seeded change to the env, at a level, that a robustness suite scores a policy
under.

A perturbation overrides the hooks it needs; the env calls every hook of every active perturbation at the point
named in its docstring (`kitbench.envs.tabletop.TabletopEnv`). Random draws come from the perturbation's own
generator for the episode (`rng`), derived from the episode's seed and the perturbation's name, so a perturbed
episode starts from the same object placement as the nominal one, and adding a second perturbation does not
change the draws of the first.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, ClassVar

import numpy as np

from kitbench.errors import KitbenchError

if TYPE_CHECKING:
    import sapien

    from kitbench.envs.tabletop import TabletopEnv
    from kitbench.sim.cameras import CameraSpec


class Perturbation:
    """A change of the env at `level` (in `unit`); subclasses override the hooks they need."""

    name: ClassVar[str]
    unit: ClassVar[str]  # what a level is measured in, for reports and errors
    description: ClassVar[str]  # one line: what the level does
    minimum: ClassVar[float] = -math.inf  # the valid levels, bounds included
    maximum: ClassVar[float] = math.inf
    integer: ClassVar[bool] = False  # levels are whole numbers (steps)
    nominal_level: ClassVar[float] = 0.0  # the level that changes nothing
    images_only: ClassVar[bool] = False  # changes camera images and nothing else

    def __init__(self, level: float):
        if isinstance(level, bool) or not isinstance(level, int | float) or not math.isfinite(level):
            raise KitbenchError(f"perturbation {self.name}: level must be a number, got {level!r}")
        if self.integer and level != int(level):
            raise KitbenchError(f"perturbation {self.name}: level must be a whole number of {self.unit}, got {level!r}")
        if not self.minimum <= level <= self.maximum:
            raise KitbenchError(
                f"perturbation {self.name}: level {level!r} is outside [{self.minimum:g}, {self.maximum:g}] {self.unit}"
            )
        self.level = int(level) if self.integer else float(level)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.level!r})"

    def check(self, env: TabletopEnv) -> None:
        """Refuse an env this perturbation cannot change (called once, when the env is made)."""
        if self.images_only and not env.observes_images:
            raise KitbenchError(
                f"perturbation {self.name} changes camera images only; obs_mode {env.obs_mode!r} has none "
                f"(use rgb or rgbd)"
            )

    # -- hooks, in the order the env calls them -------------------------------------------------------
    def start_episode(self, rng: np.random.Generator) -> None:
        """A new episode begins (before anything is built); reset per-episode state here."""

    def robot_base(self, pose: sapien.Pose, rng: np.random.Generator) -> sapien.Pose:
        """The robot's base pose in the world (the table top is z = 0)."""
        return pose

    def object_scale(self) -> float:
        """Factor on the size of the task's object (`TabletopEnv.object_scale`), read while the task builds it."""
        return 1.0

    def lighting(self, scene: sapien.Scene, rng: np.random.Generator) -> None:
        """Change the scene's lights (scenes that render only)."""

    def camera(self, spec: CameraSpec, rng: np.random.Generator) -> CameraSpec:
        """An observation camera's spec (pose relative to its mount, or to the world)."""
        return spec

    def initial_qpos(self, arm_qpos: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The arm's joint positions at reset (after the env's own initial noise)."""
        return arm_qpos

    def objects(self, env: TabletopEnv, rng: np.random.Generator) -> None:
        """Change the task's objects once the episode has placed them (`env.target_object`)."""

    def action(self, action: np.ndarray | None, env: TabletopEnv, rng: np.random.Generator) -> np.ndarray | None:
        """The action the robot executes this step, given the one asked for (None: the robot keeps its targets)."""
        return action

    def observation(self, state: dict, rng: np.random.Generator) -> dict:
        """The state observation (`TabletopEnv.state_dict()` layout) a policy sees; `rng` is this step's own."""
        return state
