"""The 20 procedurally generated kit shapes of AssemblingKits.

ManiSkill ships 20 scanned/modelled kit objects; kitbench rebuilds the task
without downloads, so each shape here is designed as the union of a few
interior-disjoint convex polygons.  That makes the collision decomposition
exact by construction (no approximate convex decomposition, no pieces sticking
out of the slot) and keeps every piece thick enough for PhysX.

Shape frame: origin at the shape's area centroid, which for a rotationally
symmetric outline is its rotation centre, z = 0 at the bottom face, extruded
up to ``SHAPE_HEIGHT``.  ``SYMMETRY[i]`` is the smallest positive yaw mapping
shape ``i`` onto itself: ``2*pi`` means none, ``0`` means any rotation (disc and
ring).  The disc and ring are regular polygons, so "any rotation" is exact only
up to their polygon step (2*pi/48 for the disc and the ring's outer edge,
2*pi/12 for the ring's inner edge); their rotation residual stays below 1%
(disc) and 2% (ring) of the area at every angle.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache

import numpy as np
import shapely
from shapely import affinity
from shapely.geometry import LineString, Polygon
from shapely.geometry.polygon import orient
from shapely.ops import unary_union

from kitbench.errors import KitbenchError
from kitbench.kits.clearance import SLOT_CLEARANCE
from kitbench.kits.convex import extrude_convex, extrude_mesh

NUM_SHAPES = 20
SHAPE_HEIGHT = 0.03
TWO_PI = 2.0 * math.pi

# Smallest self-mapping rotation per shape id (fixed by the environment contract).
SYMMETRY: tuple[float, ...] = (
    TWO_PI, TWO_PI, TWO_PI / 3, math.pi / 2, math.pi / 2,
    TWO_PI, math.pi, TWO_PI / 5, math.pi, math.pi / 2,
    TWO_PI / 5, 0.0, TWO_PI, TWO_PI, TWO_PI,
    TWO_PI, 0.0, TWO_PI / 6, TWO_PI, TWO_PI,
)  # fmt: skip

SHAPE_NAMES: tuple[str, ...] = (
    "l_block", "t_block", "triangle", "square", "plus",
    "arrow", "rectangle", "pentagon", "s_tetromino", "star4",
    "star5", "disc", "house", "right_trapezoid", "f_block",
    "kite", "ring", "hexagon", "half_disc", "chevron",
)  # fmt: skip

# Width of the pads of a parallel gripper closing across a shape from above, for callers that name no
# hand. It is the Panda's (kitbench.robots.panda.FINGER_PAD_WIDTH, held equal by tests/test_kit_physics.py),
# the one hand kitbench drives, and it is what ShapeGeometry.grasp_angle / grasp_width are computed for.
DEFAULT_PAD_WIDTH = 0.018
# Slot offsets use mitred joins; a generous limit keeps star tips mitred, not bevelled.
MITRE_LIMIT = 10.0

DISC_SEGMENTS = 48
RING_OUTER_SEGMENTS = 48
RING_INNER_SEGMENTS = 12

_MM = 1e-3

Point = tuple[float, float]
Vertices = list[Point]


# --------------------------------------------------------------------------- part builders
# Each builder returns interior-disjoint convex polygons in millimetres, in any frame;
# shape_geometry() recentres them on the area centroid and converts to metres.


def _rect(x0: float, y0: float, x1: float, y1: float) -> Vertices:
    return [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]


def _regular(n: int, radius: float, phase: float = 0.0) -> Vertices:
    return [(radius * math.cos(phase + TWO_PI * k / n), radius * math.sin(phase + TWO_PI * k / n)) for k in range(n)]


def _star(points: int, outer: float, inner: float) -> list[Vertices]:
    """Star as a central regular polygon through the inner vertices plus one triangle per tip."""
    phase = math.pi / 2
    core = _regular(points, inner, phase + math.pi / points)
    parts = [core]
    for k in range(points):
        tip = (outer * math.cos(phase + TWO_PI * k / points), outer * math.sin(phase + TWO_PI * k / points))
        parts.append([core[k - 1], tip, core[k]])
    return parts


def _l_block() -> list[Vertices]:
    return [_rect(0, 0, 14, 40), _rect(14, 0, 34, 14)]


def _t_block() -> list[Vertices]:
    return [_rect(0, 26, 40, 40), _rect(13, 0, 27, 26)]


def _triangle() -> list[Vertices]:
    return [_regular(3, 44 / math.sqrt(3), math.pi / 2)]


def _square() -> list[Vertices]:
    return [_rect(-18, -18, 18, 18)]


def _plus() -> list[Vertices]:
    return [_rect(-22, -8, 22, 8), _rect(-8, 8, 8, 22), _rect(-8, -22, 8, -8)]


def _arrow() -> list[Vertices]:
    return [_rect(0, -7, 24, 7), [(24, -18), (44, 0), (24, 18)]]


def _rectangle() -> list[Vertices]:
    return [_rect(-25, -12, 25, 12)]


def _pentagon() -> list[Vertices]:
    return [_regular(5, 23, math.pi / 2)]


def _s_tetromino() -> list[Vertices]:
    return [_rect(0, 0, 28, 14), _rect(14, 14, 42, 28)]


def _star4() -> list[Vertices]:
    return _star(4, 28, 11)


def _star5() -> list[Vertices]:
    return _star(5, 26, 11.5)


def _disc() -> list[Vertices]:
    return [_regular(DISC_SEGMENTS, 20)]


def _house() -> list[Vertices]:
    body: Vertices = [(0, 0), (32, 0), (32, 22), (16, 36), (0, 22)]

    def roof_y(x: float) -> float:  # the right roof slope
        return 22 + (32 - x) * 14 / 16

    chimney: Vertices = [(20, roof_y(20)), (30, roof_y(30)), (30, 40), (20, 40)]
    return [body, chimney]


def _right_trapezoid() -> list[Vertices]:
    return [[(0, 0), (40, 0), (24, 30), (0, 30)]]


def _f_block() -> list[Vertices]:
    return [_rect(0, 0, 12, 44), _rect(12, 32, 34, 44), _rect(12, 12, 26, 22)]


def _kite() -> list[Vertices]:
    return [[(0, -32), (18, 0), (0, 14), (-18, 0)]]


def _ring() -> list[Vertices]:
    """Annulus split into sectors of one inner edge and four outer edges each.

    Twelve sectors, not more: each is 10.4 mm across, as wide as the narrowest parts of the other shapes.
    With 24 sectors (5.4 mm) PhysX's contact generation misjudged them against the pocket walls and the
    ring jammed in 19 of 60 slightly offset drops, against 7 of 60 now (docs/kit-physics.md).
    """
    outer, inner = 21.0, 11.0
    step = RING_OUTER_SEGMENTS // RING_INNER_SEGMENTS
    parts: list[Vertices] = []
    # Angles are reduced modulo the segment count so neighbouring sectors share bit-identical
    # vertices (sin(2*pi) != sin(0) in floating point would leave a slit instead of a hole).
    for j in range(RING_INNER_SEGMENTS):
        a0 = TWO_PI * j / RING_INNER_SEGMENTS
        a1 = TWO_PI * ((j + 1) % RING_INNER_SEGMENTS) / RING_INNER_SEGMENTS
        arc = [TWO_PI * ((j * step + k) % RING_OUTER_SEGMENTS) / RING_OUTER_SEGMENTS for k in range(step + 1)]
        pts = [(inner * math.cos(a0), inner * math.sin(a0))]
        pts += [(outer * math.cos(a), outer * math.sin(a)) for a in arc]
        pts += [(inner * math.cos(a1), inner * math.sin(a1))]
        parts.append(pts)
    return parts


def _hexagon() -> list[Vertices]:
    return [_regular(6, 24)]


def _half_disc() -> list[Vertices]:
    n = 16
    return [[(25 * math.cos(math.pi * k / n), 25 * math.sin(math.pi * k / n)) for k in range(n + 1)]]


def _chevron() -> list[Vertices]:
    return [[(2, 0), (20, 0), (-2, 20), (-20, 20)], [(20, 0), (2, 0), (-20, -20), (-2, -20)]]


_BUILDERS: tuple[Callable[[], list[Vertices]], ...] = (
    _l_block, _t_block, _triangle, _square, _plus,
    _arrow, _rectangle, _pentagon, _s_tetromino, _star4,
    _star5, _disc, _house, _right_trapezoid, _f_block,
    _kite, _ring, _hexagon, _half_disc, _chevron,
)  # fmt: skip


# --------------------------------------------------------------------------- geometry


@dataclass(frozen=True, eq=False)
class ShapeGeometry:
    """Everything the env and planner need about one shape, in the shape frame (metres).

    Instances are cached and shared: treat the arrays as read-only.
    """

    shape_id: int
    name: str
    symmetry: float
    outline: Polygon
    height: float
    convex_polygons: tuple[np.ndarray, ...]  # (k,2) float64, CCW, interior-disjoint
    convex_pieces: list[np.ndarray]  # (2k,3) float32 prism vertices, z in [0, height]
    visual_vertices: np.ndarray  # (N,3) float32
    visual_faces: np.ndarray  # (M,3) int32
    footprint_radius: float  # max distance of the outline from the origin
    area: float
    grasp_angle: float  # finger closing direction (rad, shape frame) with the narrowest grasp
    grasp_width: float  # outline width across the pads at grasp_angle (both for DEFAULT_PAD_WIDTH pads)
    scale: float = 1.0  # the size against the standard shape's (footprint and height)


def check_shape_id(shape_id: object) -> int:
    """Validate a shape id, naming the bad value and the valid range (errors surface in env configs)."""
    if isinstance(shape_id, (bool, np.bool_)) or not isinstance(shape_id, (int, np.integer)):
        raise KitbenchError(f"shape id must be an int in 0..{NUM_SHAPES - 1}, got {shape_id!r}")
    if not 0 <= int(shape_id) < NUM_SHAPES:
        raise KitbenchError(f"unknown shape id {int(shape_id)} (valid: 0..{NUM_SHAPES - 1})")
    return int(shape_id)


@cache
def _parts_and_outline(shape_id: int) -> tuple[tuple[np.ndarray, ...], Polygon]:
    """Convex parts (metres, CCW, centroid at origin) and their union."""
    raw = [Polygon(np.asarray(p, dtype=np.float64) * _MM) for p in _BUILDERS[shape_id]()]
    union = unary_union(raw)
    if not isinstance(union, Polygon):
        raise AssertionError(f"shape {shape_id}: parts do not form one connected polygon")
    if abs(sum(p.area for p in raw) - union.area) > 1e-9 * union.area:
        raise AssertionError(f"shape {shape_id}: convex parts overlap")
    cx, cy = union.centroid.x, union.centroid.y
    outline = orient(affinity.translate(union, -cx, -cy), 1.0)
    parts = tuple(np.asarray(orient(p, 1.0).exterior.coords)[:-1] - (cx, cy) for p in raw)
    return parts, outline


def shape_outline(shape_id: int) -> Polygon:
    """The shape's 2D outline in the shape frame (holes kept: the ring has one)."""
    return _parts_and_outline(check_shape_id(shape_id))[1]


def check_scale(scale: object) -> float:
    """Validate a kit's scale (a kit built smaller for a smaller hand), naming the bad value."""
    if isinstance(scale, (bool, np.bool_)) or not isinstance(scale, (int, float, np.floating, np.integer)):
        raise KitbenchError(f"kit scale must be a number in (0, 2], got {scale!r}")
    if not 0.0 < float(scale) <= 2.0:
        raise KitbenchError(f"kit scale must be a number in (0, 2], got {scale!r}")
    return float(scale)


@cache
def _scaled_parts_and_outline(shape_id: int, scale: float) -> tuple[tuple[np.ndarray, ...], Polygon]:
    """The convex parts and outline with their footprint scaled about the centroid (the origin)."""
    parts, outline = _parts_and_outline(shape_id)
    if scale == 1.0:
        return parts, outline
    return tuple(p * scale for p in parts), affinity.scale(outline, scale, scale, origin=(0.0, 0.0))


@cache
def _cached_geometry(shape_id: int, scale: float = 1.0) -> ShapeGeometry:
    parts, outline = _scaled_parts_and_outline(shape_id, scale)
    height = SHAPE_HEIGHT * scale
    pieces = [extrude_convex(p, 0.0, height) for p in parts]
    vv, vf = extrude_mesh(outline, 0.0, height)
    coords = np.vstack([np.asarray(outline.exterior.coords)] + [np.asarray(r.coords) for r in outline.interiors])
    angle, width = _narrowest_grasp(outline, DEFAULT_PAD_WIDTH)
    return ShapeGeometry(
        shape_id=shape_id,
        name=SHAPE_NAMES[shape_id],
        symmetry=SYMMETRY[shape_id],
        outline=outline,
        height=height,
        convex_polygons=parts,
        convex_pieces=pieces,
        visual_vertices=vv,
        visual_faces=vf,
        footprint_radius=float(np.linalg.norm(coords, axis=1).max()),
        area=float(outline.area),
        grasp_angle=angle,
        grasp_width=width,
        scale=scale,
    )


def shape_geometry(shape_id: int, scale: float = 1.0) -> ShapeGeometry:
    """Cached geometry of one shape, `scale` times the standard one in every dimension; KitbenchError for ids
    outside 0..19 or non-ints, or a scale outside (0, 2]."""
    return _cached_geometry(check_shape_id(shape_id), check_scale(scale))


def all_shapes() -> list[ShapeGeometry]:
    return [shape_geometry(i) for i in range(NUM_SHAPES)]


# --------------------------------------------------------------------------- slots


def offset_outline(outline: Polygon, clearance: float) -> Polygon:
    """Exterior of `outline` (holes dropped) grown by `clearance` with mitred corners.

    Mitred (not rounded) joins keep the slot a true polygon with the shape's
    own corners, so a seated shape has exactly `clearance` of play on every
    straight side.
    """
    solid = Polygon(outline.exterior)
    if clearance == 0:
        return orient(solid, 1.0)
    grown = solid.buffer(clearance, join_style="mitre", mitre_limit=MITRE_LIMIT)
    return orient(grown, 1.0)


@cache
def _cached_slot(shape_id: int, clearance: float, scale: float) -> Polygon:
    return offset_outline(_scaled_parts_and_outline(shape_id, scale)[1], clearance)


def slot_outline(shape_id: int, clearance: float | None = None, scale: float = 1.0) -> Polygon:
    """The pocket outline for a shape (`scale` times the standard) in the shape frame: its exterior grown
    by `clearance` per side (default: the shape's own, `clearance.SLOT_CLEARANCE`, times `scale`: the same largest
    seated yaw)."""
    shape_id = check_shape_id(shape_id)
    scale = check_scale(scale)
    if clearance is None:
        clearance = SLOT_CLEARANCE[shape_id] * scale
    if not clearance >= 0:
        raise KitbenchError(f"clearance must be >= 0, got {clearance!r}")
    return _cached_slot(shape_id, float(clearance), scale)


def place(poly: Polygon, x: float, y: float, yaw: float) -> Polygon:
    """Transform a shape-frame polygon to a pose in the kit frame (rotate about origin, then translate)."""
    rotated = affinity.rotate(poly, yaw, origin=(0.0, 0.0), use_radians=True)
    return affinity.translate(rotated, x, y)


# --------------------------------------------------------------------------- symmetry


def rotational_symmetry_residual(polygon: Polygon, angle: float) -> float:
    """Area of (polygon XOR polygon rotated about the origin by `angle`) / polygon area.

    Zero for a rotation in the shape's symmetry group; used to verify SYMMETRY
    numerically instead of trusting the hand-written table.
    """
    rotated = affinity.rotate(polygon, angle, origin=(0.0, 0.0), use_radians=True)
    return float(polygon.symmetric_difference(rotated).area / polygon.area)


# --------------------------------------------------------------------------- grasping


def _strip_width(outline: Polygon, theta: float, pad_width: float, center: Point) -> float:
    """Extent along (cos, sin)(theta) of the outline inside the pads' sweep through `center`."""
    u = np.array([math.cos(theta), math.sin(theta)])
    n = np.array([-u[1], u[0]])
    reach = 1.0  # metres: far beyond any shape
    c = np.asarray(center, dtype=np.float64)
    h = pad_width / 2
    corners = [c - reach * u - h * n, c + reach * u - h * n, c + reach * u + h * n, c - reach * u + h * n]
    swept = outline.intersection(Polygon(corners))
    if swept.is_empty:
        return 0.0
    pts = shapely.get_coordinates(swept)
    proj = pts @ u
    return float(proj.max() - proj.min())


def grasp_width_at(
    outline: Polygon, theta: float, pad_width: float = DEFAULT_PAD_WIDTH, center: Point = (0.0, 0.0)
) -> float:
    """Opening a parallel gripper needs to span `outline` closing along angle theta (shape frame).

    The fingers sweep a strip `pad_width` wide (the gripper's pad width: pass
    the hand's own) centred on the line through `center` along theta; the
    required opening is the outline's extent along theta inside that strip.
    """
    return _strip_width(outline, theta, pad_width, center)


def grasp_width(shape_id: int, theta: float, pad_width: float = DEFAULT_PAD_WIDTH, center: Point = (0.0, 0.0)) -> float:
    """Gripper opening needed to grasp shape `shape_id` through `center` closing along theta."""
    return grasp_width_at(shape_outline(shape_id), theta, pad_width, center)


def _narrowest_grasp(outline: Polygon, pad_width: float, samples: int = 180) -> tuple[float, float]:
    """Closing direction in [0, pi) with the smallest opening (ties: the smallest angle)."""
    thetas = np.arange(samples) * math.pi / samples
    widths = np.array([_strip_width(outline, float(t), pad_width, (0.0, 0.0)) for t in thetas])
    k = int(np.argmin(widths + 1e-9 * np.arange(samples)))
    return float(thetas[k]), float(widths[k])


def narrowest_grasp(shape_id: int, pad_width: float = DEFAULT_PAD_WIDTH) -> tuple[float, float]:
    """(theta, width): the closing direction through the origin needing the smallest opening."""
    if pad_width == DEFAULT_PAD_WIDTH:
        g = shape_geometry(shape_id)
        return g.grasp_angle, g.grasp_width
    return _narrowest_grasp(shape_outline(shape_id), pad_width)


def min_thickness(shape_id: int) -> float:
    """Smallest inscribed-circle diameter over the shape's convex parts (ring: its wall).

    A thin part is what PhysX and the gripper handle badly, so tests bound
    this from below.  Ring sectors are slivers by construction but the ring
    itself is a 1 cm wall, so the ring reports its radial wall instead.
    """
    outline = shape_outline(shape_id)
    if len(outline.interiors) > 0:
        ext = np.asarray(outline.exterior.coords)
        holes = np.vstack([np.asarray(r.coords) for r in outline.interiors])
        inner_max = float(np.linalg.norm(holes, axis=1).max())
        outer_min = float(LineString(ext).distance(shapely.points(0.0, 0.0)))
        return outer_min - inner_max
    parts = _parts_and_outline(shape_id)[0]
    diam: list[float] = []
    for p in parts:
        poly = Polygon(p)
        circle = shapely.maximum_inscribed_circle(poly, tolerance=1e-6)
        diam.append(2.0 * float(circle.length))
    return min(diam)


__all__ = [
    "DEFAULT_PAD_WIDTH",
    "MITRE_LIMIT",
    "NUM_SHAPES",
    "SHAPE_HEIGHT",
    "SHAPE_NAMES",
    "SYMMETRY",
    "ShapeGeometry",
    "all_shapes",
    "check_scale",
    "check_shape_id",
    "grasp_width",
    "grasp_width_at",
    "min_thickness",
    "narrowest_grasp",
    "offset_outline",
    "place",
    "rotational_symmetry_residual",
    "shape_geometry",
    "shape_outline",
    "slot_outline",
]
