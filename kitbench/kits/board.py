"""Kit board geometry: a slab with shape-shaped pockets.

The board is built as two layers so that it decomposes exactly into convex
pieces: a solid base slab under the whole board (z in [0, floor]) whose top is
every pocket's floor, and a top layer (z in [floor, top]) that is the board
rectangle minus the slot outlines.  Only the top layer is non-convex; it is
split with Hertel-Mehlhorn (see convex.py) and extruded.

PhysX collides the board as one triangle mesh of its surface (`collision_mesh`),
not as those convex pieces. A shape released with its bottom face exactly level
with the board top (1 cm above its seated pose, the pocket depth) made PhysX's
persistent contact manifold fall back on a separating-axis test between a
shape piece and a board piece, which took a face that does not separate them
(one of the shape piece's, or one where two board pieces meet) for the contact
plane and reported the shape 6-8 mm deep in a board it was 1.7 mm away from.
Over the 300 default kits, 6 of 1,200 drops 1 and 2 degrees off were jammed,
thrown out or turned non-finite (cooked at other scales, other kits failed
instead); against the mesh, none (docs/kit-physics.md). The mesh is only the
real surface: no faces inside the board, no cooked hulls.

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
from kitbench.kits.clearance import DEFAULT_CLEARANCE, SLOT_CLEARANCE
from kitbench.kits.convex import (
    box_mesh,
    cap_mesh,
    convex_decompose,
    extrude_convex,
    extrude_mesh,
    merge_meshes,
    polygon_rings,
    wall_mesh,
    weld_mesh,
)
from kitbench.kits.shapes import NUM_SHAPES, place, slot_outline

BOARD_SIZE: tuple[float, float] = (0.20, 0.28)
BOARD_TOP = 0.02
POCKET_DEPTH = 0.01
SLOT_FLOOR = BOARD_TOP - POCKET_DEPTH
# Slots keep at least this much board material to the board edge.
BOARD_MARGIN = 0.005
# Overlap tolerance (m^2): intersections smaller than this are numerical noise.
OVERLAP_AREA_TOL = 1e-9

SlotPose = tuple[int, float, float, float]  # (shape_id, x, y, yaw)
# Pocket clearance (m): one for every pocket, one per shape id, or None for each shape's own (SLOT_CLEARANCE).
Clearance = float | Sequence[float] | None


def pocket_clearances(clearance: Clearance = None, scale: float = 1.0) -> tuple[float, ...]:
    """The clearance of each shape id's pocket (m), from any form of `Clearance` (None: each shape's own, times the
    kit's `scale`)."""
    if clearance is None:
        return SLOT_CLEARANCE if scale == 1.0 else tuple(c * scale for c in SLOT_CLEARANCE)
    if isinstance(clearance, (int, float, np.floating, np.integer)):
        values = (float(clearance),) * NUM_SHAPES
    else:
        values = tuple(float(c) for c in clearance)
        if len(values) != NUM_SHAPES:
            raise KitbenchError(f"need one clearance per shape id ({NUM_SHAPES}), got {len(values)}")
    if not all(c >= 0 for c in values):
        raise KitbenchError(f"clearances must be >= 0, got {values}")
    return values


@dataclass(frozen=True, eq=False)
class BoardGeometry:
    """Collision and visual geometry of one kit board, in the kit frame (metres)."""

    size: tuple[float, float]
    top: float
    pocket_depth: float
    clearance: tuple[float, ...]  # pocket clearance per shape id
    slots: tuple[SlotPose, ...]
    slot_polygons: tuple[Polygon, ...]  # placed slot outlines, same order as `slots`
    top_polygon: Polygon | MultiPolygon  # board rectangle minus all slot outlines
    scale: float = 1.0  # the shapes' size against the standard ones' (kits.shapes.shape_geometry)

    @property
    def floor(self) -> float:
        """z of every pocket floor, where a seated shape's bottom face rests."""
        return self.top - self.pocket_depth

    @cached_property
    def top_convex_polygons(self) -> tuple[np.ndarray, ...]:
        """(k,2) float64 CCW convex pieces whose union is top_polygon (built on first use: the env collides with
        collision_mesh and never needs them)."""
        return tuple(convex_decompose(self.top_polygon))

    @cached_property
    def convex_pieces(self) -> list[np.ndarray]:
        """float32 (N,3) prisms whose union is the board: the base slab, then the top layer's pieces."""
        sx, sy = self.size
        slab = extrude_convex(np.asarray(board_rectangle((sx, sy)).exterior.coords)[:-1], 0.0, self.floor)
        return [slab] + [extrude_convex(p, self.floor, self.top) for p in self.top_convex_polygons]

    @cached_property
    def collision_mesh(self) -> tuple[np.ndarray, np.ndarray]:
        """The board's closed surface as one welded triangle mesh, faces wound outward: (vertices float32 (N,3),
        faces int32 (M,3)). Top face, pocket walls and floors, the sides and the bottom; no internal faces."""
        rect = board_rectangle(self.size)
        layer = list(self.top_polygon.geoms) if isinstance(self.top_polygon, MultiPolygon) else [self.top_polygon]
        parts = []
        for poly in layer:
            parts.append(cap_mesh(poly, self.top))
            parts.extend(wall_mesh(ring, self.floor, self.top) for ring in polygon_rings(poly))
            parts.extend(cap_mesh(Polygon(ring), self.floor) for ring in poly.interiors)
        # pockets cut into the board's edge are floors outside every exterior ring of the top layer
        notches = rect.difference(unary_union([Polygon(p.exterior) for p in layer]))
        cut = notches.geoms if isinstance(notches, MultiPolygon) else [notches]
        parts.extend(cap_mesh(poly, self.floor) for poly in cut if poly.area > OVERLAP_AREA_TOL)
        parts.extend(wall_mesh(ring, 0.0, self.floor) for ring in polygon_rings(rect))
        parts.append(cap_mesh(rect, 0.0, up=False))
        return weld_mesh(*merge_meshes(parts))

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


def placed_slot_polygons(slots: Iterable[SlotPose], clearance: Clearance = None, scale: float = 1.0) -> list[Polygon]:
    """Slot outlines moved to their kit-frame poses, each cut with its shape's clearance (`Clearance`), for shapes
    `scale` times the standard size."""
    per_shape = pocket_clearances(clearance, scale)
    return [
        place(slot_outline(int(sid), per_shape[int(sid)], scale), float(x), float(y), float(yaw))
        for sid, x, y, yaw in slots
    ]


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
    clearance: Clearance = None,
    size: Sequence[float] = BOARD_SIZE,
    top: float = BOARD_TOP,
    pocket_depth: float = POCKET_DEPTH,
    scale: float = 1.0,
) -> BoardGeometry:
    """Build the board for slots given as (shape_id, x, y, yaw) in the kit frame, each pocket cut with its shape's
    clearance (`Clearance`; default: every shape's own, SLOT_CLEARANCE) for shapes `scale` times the standard size.

    Raises ValueError if a slot leaves the board or two slots overlap, since the
    pocket layer would then not be what the episode describes.
    """
    if not 0 < pocket_depth < top:
        raise KitbenchError(f"need 0 < pocket_depth < top, got pocket_depth={pocket_depth}, top={top}")
    slots = tuple((int(s), float(x), float(y), float(w)) for s, x, y, w in slots)
    per_shape = pocket_clearances(clearance, scale)
    polys = placed_slot_polygons(slots, per_shape, scale)
    problems = layout_problems(polys, size)
    if problems:
        raise KitbenchError("invalid slot layout: " + "; ".join(f"slot {i}: {m}" for i, m in problems))
    sx, sy = float(size[0]), float(size[1])
    rect = board_rectangle(size)
    top_poly = rect.difference(unary_union(polys)) if polys else rect
    return BoardGeometry(
        size=(sx, sy),
        top=float(top),
        pocket_depth=float(pocket_depth),
        clearance=per_shape,
        slots=slots,
        slot_polygons=tuple(polys),
        top_polygon=top_poly,
        scale=float(scale),
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
    "Clearance",
    "SlotPose",
    "board_geometry",
    "board_rectangle",
    "layout_problems",
    "placed_slot_polygons",
    "pocket_clearances",
]
