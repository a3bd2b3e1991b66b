"""Kit board geometry: a slab with shape-shaped pockets.

The board is built as two layers so that it decomposes exactly into convex
pieces: a solid base slab under the whole board (z in [0, floor]) whose top is
every pocket's floor, and a top layer (z in [floor, top]) that is the board
rectangle minus the slot outlines.  Only the top layer is non-convex; it is
split with Hertel-Mehlhorn (see convex.py) and extruded.

Kit frame: board centred at xy (0, 0), table top at z = 0, +x away from the robot.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from shapely.geometry import MultiPolygon, Polygon, box
from shapely.ops import unary_union

from kitbench.errors import KitbenchError
from kitbench.kits.convex import box_mesh, convex_decompose, extrude_convex, extrude_mesh, merge_meshes
from kitbench.kits.shapes import place, slot_outline

BOARD_SIZE: tuple[float, float] = (0.20, 0.28)
BOARD_TOP = 0.02
POCKET_DEPTH = 0.01
SLOT_FLOOR = BOARD_TOP - POCKET_DEPTH
DEFAULT_CLEARANCE = 0.002
# Slots keep at least this much board material to the board edge.
BOARD_MARGIN = 0.005
# Overlap tolerance (m^2): intersections smaller than this are numerical noise.
OVERLAP_AREA_TOL = 1e-9

SlotPose = tuple[int, float, float, float]  # (shape_id, x, y, yaw)


@dataclass(frozen=True, eq=False)
class BoardGeometry:
    """Collision and visual geometry of one kit board, in the kit frame (metres)."""

    size: tuple[float, float]
    top: float
    pocket_depth: float
    clearance: float
    slots: tuple[SlotPose, ...]
    slot_polygons: tuple[Polygon, ...]  # placed slot outlines, same order as `slots`
    top_polygon: Polygon | MultiPolygon  # board rectangle minus all slot outlines
    top_convex_polygons: tuple[np.ndarray, ...]  # (k,2) float64 CCW, convex, union == top_polygon
    convex_pieces: list[np.ndarray]  # float32 (N,3): base slab box, then the top-layer prisms

    @property
    def floor(self) -> float:
        """z of every pocket floor, where a seated shape's bottom face rests."""
        return self.top - self.pocket_depth

    @cached_property
    def _visual_mesh(self) -> tuple[np.ndarray, np.ndarray]:
        """Built on first use: it is 40% of the board's build time and state-only envs never draw it."""
        sx, sy = self.size
        slab = box_mesh(-sx / 2, -sy / 2, sx / 2, sy / 2, 0.0, self.floor)
        return merge_meshes([slab, extrude_mesh(self.top_polygon, self.floor, self.top)])

    @property
    def visual_vertices(self) -> np.ndarray:
        """(N,3) float32 vertices of the board's triangle mesh (flat-shaded prism walls and caps)."""
        return self._visual_mesh[0]

    @property
    def visual_faces(self) -> np.ndarray:
        """(M,3) int32 faces into visual_vertices, wound outward."""
        return self._visual_mesh[1]


def board_rectangle(size: Sequence[float] = BOARD_SIZE) -> Polygon:
    sx, sy = float(size[0]), float(size[1])
    return box(-sx / 2, -sy / 2, sx / 2, sy / 2)


def placed_slot_polygons(slots: Iterable[SlotPose], clearance: float = DEFAULT_CLEARANCE) -> list[Polygon]:
    """Slot outlines moved to their kit-frame poses."""
    return [place(slot_outline(int(sid), clearance), float(x), float(y), float(yaw)) for sid, x, y, yaw in slots]


def layout_problems(
    slot_polygons: Sequence[Polygon],
    size: Sequence[float] = BOARD_SIZE,
    margin: float = 0.0,
    min_gap: float = 0.0,
) -> list[tuple[int, str]]:
    """(slot index, message) for every slot that leaves the board or overlaps another.

    Shared by the board builder, the episode generator (with stricter margin
    and gap) and the episode file validator, so all three agree on "valid".
    """
    problems: list[tuple[int, str]] = []
    inner = board_rectangle(size).buffer(-margin, join_style="mitre") if margin > 0 else board_rectangle(size)
    for i, poly in enumerate(slot_polygons):
        outside = poly.difference(inner).area
        if outside > OVERLAP_AREA_TOL:
            where = f"within {margin * 1e3:g} mm of the board edge" if margin > 0 else "outside the board"
            problems.append((i, f"slot outline extends {where} ({outside * 1e6:.3g} mm^2)"))
    for i in range(len(slot_polygons)):
        for j in range(i + 1, len(slot_polygons)):
            a, b = slot_polygons[i], slot_polygons[j]
            overlap = a.intersection(b).area
            if overlap > OVERLAP_AREA_TOL:
                problems.append((j, f"slot outline overlaps slot {i} ({overlap * 1e6:.3g} mm^2)"))
            elif min_gap > 0 and a.distance(b) < min_gap:
                problems.append((j, f"slot outline within {min_gap * 1e3:g} mm of slot {i}"))
    return problems


def board_geometry(
    slots: Sequence[SlotPose],
    clearance: float = DEFAULT_CLEARANCE,
    size: Sequence[float] = BOARD_SIZE,
    top: float = BOARD_TOP,
    pocket_depth: float = POCKET_DEPTH,
) -> BoardGeometry:
    """Build the board for slots given as (shape_id, x, y, yaw) in the kit frame.

    Raises ValueError if a slot leaves the board or two slots overlap, since the
    pocket layer would then not be what the episode describes.
    """
    if not 0 < pocket_depth < top:
        raise KitbenchError(f"need 0 < pocket_depth < top, got pocket_depth={pocket_depth}, top={top}")
    slots = tuple((int(s), float(x), float(y), float(w)) for s, x, y, w in slots)
    polys = placed_slot_polygons(slots, clearance)
    problems = layout_problems(polys, size)
    if problems:
        raise KitbenchError("invalid slot layout: " + "; ".join(f"slot {i}: {m}" for i, m in problems))
    floor = top - pocket_depth
    sx, sy = float(size[0]), float(size[1])
    rect = board_rectangle(size)
    top_poly = rect.difference(unary_union(polys)) if polys else rect
    top_parts = tuple(convex_decompose(top_poly))
    slab = extrude_convex(np.asarray(rect.exterior.coords)[:-1], 0.0, floor)
    pieces = [slab] + [extrude_convex(p, floor, top) for p in top_parts]
    return BoardGeometry(
        size=(sx, sy),
        top=float(top),
        pocket_depth=float(pocket_depth),
        clearance=float(clearance),
        slots=slots,
        slot_polygons=tuple(polys),
        top_polygon=top_poly,
        top_convex_polygons=top_parts,
        convex_pieces=pieces,
    )


__all__ = [
    "BOARD_MARGIN",
    "BOARD_SIZE",
    "BOARD_TOP",
    "DEFAULT_CLEARANCE",
    "OVERLAP_AREA_TOL",
    "POCKET_DEPTH",
    "SLOT_FLOOR",
    "BoardGeometry",
    "SlotPose",
    "board_geometry",
    "board_rectangle",
    "layout_problems",
    "placed_slot_polygons",
]
