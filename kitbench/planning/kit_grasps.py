"""Where a kit shape can be gripped between two fingers, for the AssemblingKits expert: the opening each closing
direction through its centroid needs, where flat jaws meet its outline, which directions close across its narrowest
width, and the turns that bring it to its slot's yaw under its symmetry."""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from kitbench.kits import shape_geometry
from kitbench.kits.shapes import grasp_width_at

CLOSING_SAMPLES = 36  # closing directions tried, over 180 degrees


@lru_cache(maxsize=64)
def closing_widths(shape_id: int, scale: float = 1.0) -> tuple[tuple[float, float], ...]:
    """(angle in the shape frame, opening needed) for closing directions through the centroid of the shape,
    `scale` times the standard one."""
    outline = shape_geometry(shape_id, scale).outline
    angles = np.arange(CLOSING_SAMPLES) * math.pi / CLOSING_SAMPLES
    return tuple((float(a), grasp_width_at(outline, float(a))) for a in angles)


FACE_TOLERANCE = 0.0005  # m: outline within this of its extreme along the closing direction bears on a jaw


@dataclass(frozen=True)
class JawContact:
    """Where a flat jaw meets a shape's outline from behind or ahead along a closing direction (shape frame):
    how far from the centroid (m, signed along the direction) and how wide a face it meets (m, ~0 at a corner)."""

    behind_at: float
    behind_face: float
    ahead_at: float
    ahead_face: float


@lru_cache(maxsize=64)
def jaw_contacts(shape_id: int, scale: float = 1.0) -> tuple[JawContact, ...]:
    """A `JawContact` for each closing direction of `closing_widths`."""
    outline = shape_geometry(shape_id, scale).outline
    boundary = outline.exterior
    points = np.asarray([boundary.interpolate(d).coords[0] for d in np.arange(0.0, boundary.length, 2e-4)])
    out = []
    for angle in np.arange(CLOSING_SAMPLES) * math.pi / CLOSING_SAMPLES:
        u = np.array([math.cos(angle), math.sin(angle)])
        along, across = points @ u, points @ np.array([-u[1], u[0]])
        sides = (float(along.min()), float(along.max()))
        spans = []
        for side in sides:
            touching = across[np.abs(along - side) <= FACE_TOLERANCE]
            spans.append(float(touching.max() - touching.min()))
        out.append(JawContact(sides[0], spans[0], sides[1], spans[1]))
    return tuple(out)


def grip_period(symmetry: float) -> float:
    """The turn (rad) after which a shape of this symmetry sits alike between two fingers: its symmetry combined
    with the hand's half turn (closing along a direction or its opposite is one grasp); 0 for a disc or a ring."""
    if symmetry <= 0:
        return 0.0
    return math.radians(math.gcd(round(math.degrees(symmetry) * 1000), 180_000) / 1000.0)


def across_narrowest(angle: float, grasp_angle: float, symmetry: float) -> bool:
    """Whether closing along `angle` (rad, shape frame) is closing along `grasp_angle` up to `grip_period`, to
    within half a sampled direction."""
    period = grip_period(symmetry)
    if not period:
        return True  # a disc or a ring: every direction is the narrowest
    off = (angle - grasp_angle) % period
    return min(off, period - off) <= math.pi / (2 * CLOSING_SAMPLES) + 1e-9


def signed_yaw_options(delta: float, symmetry: float) -> list[float]:
    """Rotations of the shape (rad, signed, within +-2 pi) that bring its yaw to the goal yaw: `delta` (the
    wrapped difference) plus any multiple of the symmetry angle; any rotation at all, 0 included, for a disc."""
    if symmetry <= 0:
        return [0.0]
    out = []
    k = math.floor((-2 * math.pi - delta) / symmetry)
    while delta + k * symmetry <= 2 * math.pi + 1e-9:
        value = delta + k * symmetry
        if abs(value) <= 2 * math.pi + 1e-9:
            out.append(value)
        k += 1
    return out
