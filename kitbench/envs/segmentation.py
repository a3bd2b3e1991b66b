"""Stable segmentation ids: what a pixel shows, labelled the same way in every episode of an env.

SAPIEN labels a pixel with the `per_scene_id` of the entity it sees, which depends on the order a scene was
built in, and kitbench builds a new scene every episode (AssemblingKits a different kit each time). So the env
keeps its own table (`TabletopEnv.segmentation_id_map`): `SEGMENTATION_FIXED`, the robot's links in its model's
order, then the task's `segmentation_names()`; each scene maps its entity ids onto it through one lookup table,
a single indexing of the picture per camera.
"""

from __future__ import annotations

import numpy as np
import sapien

from kitbench.errors import KitbenchError

# The ids below the robot's links: what a pixel that sees nothing, the ground and the table read.
SEGMENTATION_FIXED = ("background", "ground", "table")


def segmentation_lut(scene: sapien.Scene, robot, id_map: dict[int, str], task: type) -> np.ndarray:
    """uint16 table from this scene's `per_scene_id`s to the stable ids of `id_map`, by entity name. A visible
    entity whose name the table lacks is refused, naming the `task`'s hook that declares it."""
    stable = {name: i for i, name in id_map.items()}
    entities = scene.entities
    lut = np.zeros(max(e.per_scene_id for e in entities) + 1, dtype=np.uint16)
    for entity in entities:
        if entity.find_component_by_type(sapien.render.RenderBodyComponent) is None:
            continue  # lights and cameras never show in a picture
        if entity.name not in stable:
            raise KitbenchError(
                f"{task.__name__} shows an actor named {entity.name!r} that has no segmentation id: "
                f"add it to segmentation_names() (known: {', '.join(stable)})"
            )
        lut[entity.per_scene_id] = stable[entity.name]
    for link in robot.articulation.links:  # a link's entity may render through its visual bodies only
        lut[link.entity.per_scene_id] = stable[link.name]
    return lut
