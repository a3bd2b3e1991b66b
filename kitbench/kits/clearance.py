"""Pocket clearance per shape: the play a pocket leaves is what lets a wrongly turned shape in.

AssemblingKits counts a shape as placed when it sits in its pocket (`in_slot`) *and* its yaw is within 4 degrees
of the slot's (modulo its symmetry). The two must agree physically: a shape that can sit in its pocket turned
further than that would be in_slot yet fail, and no policy could tell from the kit why. So every pocket's
clearance c (the outline grown by c per side, mitred: `shapes.offset_outline`) is chosen from the largest yaw at
which the shape still fits it, `MAX_SEATED_YAW`: the 4-degree success tolerance less a 0.5-degree margin that keeps
the success test's own threshold clear of the contact solver (in PhysX the simulated limit lies within 0.1 degree
of the one computed here: bench/kit_drops.py, docs/kit-physics.md).

How far a shape can turn in its pocket. Turned by yaw about its origin, a shape fits a pocket of clearance c if
some shift t puts it inside. For the small yaws that matter (corners stay near their own corners), that is linear
in (t, c): each convex corner of the outline must stay inside the two offset edges it meets, and each reflex
corner of the pocket (where it pokes into the shape) must stay outside the two turned edges of the shape it
faces. `required_clearance` solves that linear programme (minimise c over t and c) and `max_seated_yaw` inverts
it. Shapely containment agrees to 1e-7 m (tests/test_kit_clearance.py). The shift matters: the half disc turned
2 degrees about its centroid needs 0.87 mm, shifted half a millimetre 0.47 mm. The more symmetric the polygon, the
smaller the clearance that already lets it turn: at the old uniform 2 mm, a hexagon fits 11.7 degrees off and a
square 6.8; at 1 mm, 5.2 and 3.3.

The clearance for MAX_SEATED_YAW, rounded down to 0.01 mm, per shape, and the yaw the shape then fits at, turning
counter-clockwise / clockwise where the two differ (the disc and the ring fit at every yaw and keep
DEFAULT_CLEARANCE):

     id shape            clearance  turns at most (ccw / cw)   at 2 mm (before)
      0 l_block           1.18 mm   3.47 / 3.42                6.01 / 5.84
      1 t_block           1.20 mm   3.48                       5.84
      2 triangle          1.31 mm   3.47                       5.36
      3 square            1.06 mm   3.48                       6.78
      4 plus              1.32 mm   3.48                       5.31
      5 arrow             1.11 mm   3.47                       6.34
      6 rectangle         1.50 mm   3.49                       4.68
      7 pentagon          0.79 mm   3.50                       9.63
      8 s_tetromino       1.25 mm   3.48 / 3.41                5.65 / 5.47
      9 star4             1.57 mm   3.49                       4.46
     10 star5             1.45 mm   3.49                       4.84
     11 disc              2.00 mm   any                        any
     12 house             1.19 mm   3.44 / 3.49                5.83 / 5.97
     13 right_trapezoid   1.14 mm   3.48 / 3.34                6.23 / 5.97
     14 f_block           1.31 mm   3.44 / 3.50                5.28 / 5.41
     15 kite              1.02 mm   3.49                       7.03
     16 ring              2.00 mm   any                        any
     17 hexagon           0.69 mm   3.48                       11.69
     18 half_disc         0.81 mm   3.49                       9.05
     19 chevron           1.30 mm   3.49                       5.40

(`python bench/kit_drops.py` prints these limits for the pockets in use, next to the ones PhysX shows; at 2 mm they
are what it printed before.) The smallest clearance, the hexagon's 0.69 mm, is what the expert's re-aim over the
slot has to hit (kitbench/planning/assembling_kits.py).
"""

from __future__ import annotations

import math

import numpy as np
from shapely.geometry import Polygon

# Pocket clearance per side (m) of a shape that fits its pocket at any yaw (disc, ring), of every pocket in an
# episode file of format version 1, and the spacing the episode generator lays pockets out with.
DEFAULT_CLEARANCE = 0.002
# The success test's yaw tolerance (tasks/assembling_kits.py ROT_TOLERANCE, equal by tests/test_kit_clearance.py)
# less a margin: the largest yaw at which a shape may fit its pocket.
SUCCESS_YAW_TOLERANCE = math.radians(4.0)
YAW_MARGIN = math.radians(0.5)
MAX_SEATED_YAW = SUCCESS_YAW_TOLERANCE - YAW_MARGIN
# Clearances are rounded down to this (m): never above what MAX_SEATED_YAW allows, and exact in an episode file.
CLEARANCE_STEP = 1e-5
# The linear model holds while the outline's corners stay near their own; every limit here is below this.
MAX_MODELLED_YAW = math.radians(15.0)

# Per shape id (m): the clearance for MAX_SEATED_YAW, rounded down (table above; tests/test_kit_clearance.py
# recomputes it). Fixed numbers, not recomputed at import, so pockets never move with a solver's rounding.
SLOT_CLEARANCE: tuple[float, ...] = (
    0.00118, 0.00120, 0.00131, 0.00106, 0.00132,
    0.00111, 0.00150, 0.00079, 0.00125, 0.00157,
    0.00145, 0.00200, 0.00119, 0.00114, 0.00131,
    0.00102, 0.00200, 0.00069, 0.00081, 0.00130,
)  # fmt: skip


def _corners(outline: Polygon) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, bool, np.ndarray]]:
    """(vertex, normal of the edge in, normal of the edge out, convex?, mitre vector) per corner of the exterior.

    Normals are unit and outward; the mitre vector m is where the corner moves when both edges move out by 1
    (n_in . m = n_out . m = 1). Straight-through vertices are skipped: a straight edge constrains only at its ends.
    """
    solid = Polygon(outline.exterior)
    pts = np.asarray(solid.exterior.coords, dtype=np.float64)[:-1]
    if solid.exterior.is_ccw is False:
        pts = pts[::-1]
    size = float(np.ptp(pts, axis=0).max())
    corners = []
    for i in range(len(pts)):
        before, at, after = pts[i - 1], pts[i], pts[(i + 1) % len(pts)]
        e_in, e_out = at - before, after - at
        cross = e_in[0] * e_out[1] - e_in[1] * e_out[0]
        if abs(cross) <= 1e-12 * size * size:
            continue
        n_in = np.array([e_in[1], -e_in[0]]) / np.linalg.norm(e_in)
        n_out = np.array([e_out[1], -e_out[0]]) / np.linalg.norm(e_out)
        mitre = np.linalg.solve(np.array([n_in, n_out]), np.ones(2))
        corners.append((at, n_in, n_out, bool(cross > 0), mitre))
    return corners


def required_clearance(outline: Polygon, yaw: float) -> tuple[float, tuple[float, float]]:
    """The smallest clearance (m) at which `outline` (holes ignored) turned by `yaw` (rad) about its origin fits
    its pocket, and the shift (m, shape frame) that fits it there; for |yaw| up to MAX_MODELLED_YAW."""
    # Imported here: scipy.optimize takes over a second to import, and only the analysis (tests, bench) needs it,
    # not the env (it reads SLOT_CLEARANCE). scipy has no type information (no py.typed marker, no stubs installed).
    from scipy.optimize import linprog  # type: ignore[import-untyped]

    c, s = math.cos(yaw), math.sin(yaw)
    turn = np.array([[c, -s], [s, c]])
    rows: list[list[float]] = []
    bounds: list[float] = []
    for vertex, n_in, n_out, convex, mitre in _corners(outline):
        for n in (n_in, n_out):
            if convex:  # the turned, shifted corner inside the pocket edge: n.(R v + t) <= n.v + c
                rows.append([n[0], n[1], -1.0])
                bounds.append(float(n @ vertex - n @ (turn @ vertex)))
            else:  # the pocket's corner v + c m outside the turned edge: (R n).(v + c m - t) >= n.v
                rn = turn @ n
                rows.append([rn[0], rn[1], -float(rn @ mitre)])
                bounds.append(float(rn @ vertex - n @ vertex))
    result = linprog([0.0, 0.0, 1.0], A_ub=rows, b_ub=bounds, bounds=[(None, None)] * 3, method="highs")
    if result.status != 0:
        raise ArithmeticError(f"clearance programme failed: {result.message}")
    return max(0.0, float(result.x[2])), (float(result.x[0]), float(result.x[1]))


def max_seated_yaw(outline: Polygon, clearance: float, limit: float = MAX_MODELLED_YAW, sense: float = 0.0) -> float:
    """The largest yaw (rad) at which `outline` fits a pocket of `clearance`, searched up to `limit`: turning
    counter-clockwise (sense > 0), clockwise (sense < 0) or, by default, the smaller of the two. Bisection on
    required_clearance, which grows with the yaw."""
    if sense == 0.0:
        return min(max_seated_yaw(outline, clearance, limit, 1.0), max_seated_yaw(outline, clearance, limit, -1.0))
    sign = math.copysign(1.0, sense)
    if required_clearance(outline, sign * limit)[0] <= clearance:
        return limit
    lo, hi = 0.0, limit
    for _ in range(32):
        mid = 0.5 * (lo + hi)
        if required_clearance(outline, sign * mid)[0] <= clearance:
            lo = mid
        else:
            hi = mid
    return lo


def clearance_for_yaw(outline: Polygon, yaw: float = MAX_SEATED_YAW) -> float:
    """The largest clearance (m) at which `outline` fits its pocket turned by `yaw` in neither sense, rounded down
    to CLEARANCE_STEP."""
    exact = min(required_clearance(outline, yaw)[0], required_clearance(outline, -yaw)[0])
    return math.floor(exact / CLEARANCE_STEP + 1e-9) * CLEARANCE_STEP


def slot_clearance(shape_id: int) -> float:
    """The clearance (m) of shape `shape_id`'s pocket in the default kits."""
    return SLOT_CLEARANCE[shape_id]


__all__ = [
    "CLEARANCE_STEP",
    "DEFAULT_CLEARANCE",
    "MAX_MODELLED_YAW",
    "MAX_SEATED_YAW",
    "SLOT_CLEARANCE",
    "SUCCESS_YAW_TOLERANCE",
    "YAW_MARGIN",
    "clearance_for_yaw",
    "max_seated_yaw",
    "required_clearance",
    "slot_clearance",
]
