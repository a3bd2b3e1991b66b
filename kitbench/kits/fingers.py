"""Where the Panda's open fingertips come down around an AssemblingKits shape, and how clear of obstacles they are.

The expert chooses its grasp's closing direction by these clearances (planning/assembling_kits.py), and
studies/assembling_kits_grasp/grasp_misses.py measures a policy's grasps by them: a learned policy that misses the
grasp has, in most episodes traced, closed along a direction whose fingertips come down on a seated shape
(docs/studies/assembling-kits-grasp.md).
"""

from __future__ import annotations

import math

import numpy as np
from shapely.geometry import Polygon, box

from kitbench.kits.shapes import place, shape_geometry

# The open fingertips' lowest boxes (Panda collision geometry, TCP frame): 4.0 to 5.5 cm out along the closing
# direction, 1.8 cm across it. The fingers open fully before every grasp, so this is where they come down.
FINGERTIP_CENTER = 0.0476  # m from the TCP along the closing direction
FINGER_THICKNESS = 0.016  # m, along the closing direction
FINGER_WIDTH = 0.018  # m, across it
CLEAR_ENOUGH = 0.012  # m between a fingertip and an obstacle beyond which more does not matter
# Another hand's pads, each (from, to, half-width): the stretch along the closing direction from the TCP (m) that the
# pad's lowest part covers while the hand closes, and half its width across it.
Pad = tuple[float, float, float]


def finger_footprints(center, angle: float, swept: bool = False, pads: tuple[Pad, ...] | None = None) -> list[Polygon]:
    """Where the two open fingertips come down (table plane) for a grasp closing along `angle`; `swept`: all they
    pass over while they close, from there in to `center` (the shape's own outline lies in between). `pads`:
    another hand's (`center` its TCP), instead of the Panda's."""
    u = np.array([math.cos(angle), math.sin(angle)])
    if pads is not None:
        boxes = [box(a, -w, b, w) for a, b, w in pads]
        return [place(p, float(center[0]), float(center[1]), angle) for p in boxes]
    outer = FINGERTIP_CENTER + FINGER_THICKNESS / 2
    inner = 0.0 if swept else FINGERTIP_CENTER - FINGER_THICKNESS / 2
    out = []
    for sign in (-1.0, 1.0):
        c = np.asarray(center[:2]) + sign * (outer + inner) / 2 * u
        pad = box(-(outer - inner) / 2, -FINGER_WIDTH / 2, (outer - inner) / 2, FINGER_WIDTH / 2)
        out.append(place(pad, c[0], c[1], angle))
    return out


def fingertip_clearance(
    center, angle: float, obstacles: list[Polygon], swept: bool = False, pads: tuple[Pad, ...] | None = None
) -> float:
    """Distance (m) between the fingertips' footprints for a grasp at `center` closing along `angle` and the
    nearest obstacle; 1.0 with none."""
    footprints = finger_footprints(center, angle, swept, pads)
    return min((p.distance(o) for p in footprints for o in obstacles), default=1.0)


def seated_outlines(episode, scale: float = 1.0) -> list[Polygon]:
    """Outlines of the shapes seated in the kit (`scale` times the standard shapes): standing proud of the board,
    fingertips must not come down on them."""
    slots = [episode.slots[i] for i in episode.obj_in_place]
    return [place(shape_geometry(s.shape_id, scale).outline, s.pos[0], s.pos[1], s.yaw) for s in slots]


def pick_obstacles(episode, board, shape_z: float) -> list[Polygon]:
    """Around the shape where it lies (`shape_z`: the height of its origin, its bottom face): the board's edge for a
    shape on the table (the fingertips go below the board top), the seated shapes for a shape on the board."""
    if shape_z < board.top / 2:
        return [box(-board.size[0] / 2, -board.size[1] / 2, board.size[0] / 2, board.size[1] / 2)]
    return seated_outlines(episode, board.scale)
