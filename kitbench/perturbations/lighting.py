"""Lighting unlike the training scenes: brighter or darker, or tinted."""

from __future__ import annotations

import numpy as np
import sapien

from kitbench.perturbations.base import Perturbation
from kitbench.perturbations.registry import register_perturbation


def _scale_lights(scene: sapien.Scene, factors: np.ndarray) -> None:
    """Multiply the ambient light and every light's RGB colour by `factors` (3,)."""
    scene.ambient_light = np.asarray(scene.ambient_light, dtype=np.float64) * factors
    for entity in scene.entities:
        for component in entity.components:
            if isinstance(component, sapien.render.RenderLightComponent):
                component.color = np.asarray(component.color, dtype=np.float64) * factors


@register_perturbation
class LightIntensity(Perturbation):
    name = "light_intensity"
    unit = "×"
    description = "every light (ambient and directional) `level` times as bright (0.5: half, 2: double)"
    minimum, maximum = 0.0, 10.0
    nominal_level = 1.0
    images_only = True

    def lighting(self, scene, rng):
        _scale_lights(scene, np.full(3, self.level))


@register_perturbation
class LightColor(Perturbation):
    name = "light_color"
    unit = "fraction"
    description = "each light's red, green and blue scaled by 1 + u, u drawn uniformly in [-level, level] per channel"
    minimum, maximum = 0.0, 1.0
    images_only = True

    def lighting(self, scene, rng):
        _scale_lights(scene, 1.0 + rng.uniform(-self.level, self.level, 3))
