"""The perturbations one env runs under, and each one's random stream for the current episode."""

from __future__ import annotations

import zlib
from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np

from kitbench.errors import KitbenchError
from kitbench.perturbations.base import Perturbation
from kitbench.perturbations.registry import PERTURBATIONS, make_perturbation

if TYPE_CHECKING:
    import sapien

    from kitbench.envs.tabletop import TabletopEnv
    from kitbench.sim.cameras import CameraSpec


def _stream(name: str) -> int:
    """A perturbation's stream id: from its name, so that registering another perturbation changes no draw."""
    return zlib.crc32(name.encode())


class Perturbations:
    """`{name: level}` as perturbation objects (none: the nominal env), applied in registry order whatever order
    they were given in, each drawing from its own generator for the episode."""

    def __init__(self, levels: Mapping[str, float] | None = None):
        if levels is None:
            levels = {}
        if not isinstance(levels, Mapping):
            raise KitbenchError(
                f"perturbations must map a perturbation name to a level, e.g. {{'camera_pose': 2}}, got {levels!r}"
            )
        made = {name: make_perturbation(name, level) for name, level in levels.items()}
        self.active: tuple[Perturbation, ...] = tuple(made[n] for n in PERTURBATIONS if n in made)
        self.changes_observations = any(type(p).observation is not Perturbation.observation for p in self.active)
        self._key = 0
        self._rngs: list[np.random.Generator] = []

    def __bool__(self) -> bool:
        return bool(self.active)

    def to_dict(self) -> dict[str, float]:
        """`{name: level}`, as given (what reports and episode configs record)."""
        return {p.name: p.level for p in self.active}

    def check(self, env: TabletopEnv) -> None:
        for p in self.active:
            p.check(env)

    def start_episode(self, key: int) -> None:
        """A new episode whose draws all derive from `key` (the episode's seed)."""
        self._key = int(key)
        self._rngs = [np.random.default_rng([self._key, _stream(p.name)]) for p in self.active]
        for p, rng in zip(self.active, self._rngs, strict=True):
            p.start_episode(rng)

    # -- the hooks, each applied by every active perturbation in turn ---------------------------------
    def robot_base(self, pose: sapien.Pose) -> sapien.Pose:
        for p, rng in zip(self.active, self._rngs, strict=True):
            pose = p.robot_base(pose, rng)
        return pose

    def object_scale(self) -> float:
        scale = 1.0
        for p in self.active:
            scale *= p.object_scale()
        return scale

    def lighting(self, scene: sapien.Scene) -> None:
        for p, rng in zip(self.active, self._rngs, strict=True):
            p.lighting(scene, rng)

    def camera(self, spec: CameraSpec) -> CameraSpec:
        for p, rng in zip(self.active, self._rngs, strict=True):
            spec = p.camera(spec, rng)
        return spec

    def initial_qpos(self, arm_qpos: np.ndarray) -> np.ndarray:
        for p, rng in zip(self.active, self._rngs, strict=True):
            arm_qpos = p.initial_qpos(arm_qpos, rng)
        return arm_qpos

    def objects(self, env: TabletopEnv) -> None:
        for p, rng in zip(self.active, self._rngs, strict=True):
            p.objects(env, rng)

    def action(self, action: np.ndarray, env: TabletopEnv) -> np.ndarray | None:
        executed: np.ndarray | None = action
        for p, rng in zip(self.active, self._rngs, strict=True):
            executed = p.action(executed, env, rng)
        return executed

    def observation(self, state: dict, step: int) -> dict:
        """The observation at control step `step` of the episode: the same for every call in one step (a policy
        and a recorder reading it twice see one measurement), fresh at the next."""
        for p in self.active:
            state = p.observation(state, np.random.default_rng([self._key, _stream(p.name), 1, step]))
        return state
