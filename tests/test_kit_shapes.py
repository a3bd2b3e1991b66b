"""Kit shapes, slots, convex decomposition and board geometry (pure geometry, no simulator)."""

from __future__ import annotations

import ast
import math
from pathlib import Path

import numpy as np
import pytest
import shapely
from scipy.spatial import ConvexHull
from shapely.geometry import Polygon, box
from shapely.ops import unary_union

import kitbench.kits as kits
from kitbench.kits.board import BOARD_SIZE, POCKET_DEPTH, SLOT_FLOOR, board_geometry, pocket_clearances
from kitbench.kits.clearance import SLOT_CLEARANCE
from kitbench.kits.convex import convex_decompose, extrude_convex, is_convex_polygon, mesh_volume
from kitbench.kits.shapes import (
    DEFAULT_PAD_WIDTH,
    MITRE_LIMIT,
    NUM_SHAPES,
    SHAPE_HEIGHT,
    SYMMETRY,
    grasp_width,
    grasp_width_at,
    min_thickness,
    narrowest_grasp,
    place,
    rotational_symmetry_residual,
    shape_geometry,
    slot_outline,
)

SHAPE_IDS = list(range(NUM_SHAPES))
TWO_PI = 2 * math.pi
DEG = math.pi / 180


# --------------------------------------------------------------------------- helpers


def _prism_is_convex_and_exact(piece: np.ndarray, z0: float, z1: float) -> Polygon:
    """Check one prism's dtype/z-range and that its hull is the prism itself; return its 2D footprint."""
    assert piece.dtype == np.float32 and piece.ndim == 2 and piece.shape[1] == 3
    assert piece[:, 2].min() == pytest.approx(z0, abs=1e-7)
    assert piece[:, 2].max() == pytest.approx(z1, abs=1e-7)
    footprint = np.asarray(piece[piece[:, 2] < (z0 + z1) / 2][:, :2], dtype=np.float64)
    assert is_convex_polygon(footprint)
    poly = Polygon(footprint)
    hull = ConvexHull(piece.astype(np.float64)).volume
    # float32 vertices: compare at float32 resolution
    assert hull == pytest.approx(poly.area * (z1 - z0), rel=1e-5)
    return poly


def _assert_exact_partition(pieces: list[Polygon], target, rel: float):
    union = unary_union(pieces)
    assert union.symmetric_difference(target).area <= rel * target.area
    assert sum(p.area for p in pieces) == pytest.approx(target.area, rel=rel)  # interior-disjoint


# --------------------------------------------------------------------------- symmetry


def test_symmetry_table_is_the_contract():
    pi = math.pi
    expected = [2 * pi, 2 * pi, 2 * pi / 3, pi / 2, pi / 2, 2 * pi, pi, 2 * pi / 5, pi, pi / 2,
                2 * pi / 5, 0, 2 * pi, 2 * pi, 2 * pi, 2 * pi, 0, 2 * pi / 6, 2 * pi, 2 * pi]  # fmt: skip
    assert len(SYMMETRY) == NUM_SHAPES == 20
    assert SYMMETRY == pytest.approx(expected)
    assert all(shape_geometry(i).symmetry == SYMMETRY[i] for i in SHAPE_IDS)


@pytest.mark.parametrize("shape_id", SHAPE_IDS)
def test_symmetry_matches_the_outline(shape_id):
    outline = shape_geometry(shape_id).outline
    sym = SYMMETRY[shape_id]
    angles = np.arange(1, 360) * DEG
    residuals = np.array([rotational_symmetry_residual(outline, a) for a in angles])
    if sym == 0:  # disc and ring: any rotation, up to the polygon step (the ring's hole is a 12-gon, whose
        # 15-degree turn moves 1.5% of the ring's area; finer steps make sectors too thin for PhysX)
        assert residuals.max() < (0.02 if shape_id == 16 else 0.01)
    elif sym == TWO_PI:  # no rotational symmetry at all
        keep = (angles >= 2 * DEG) & (angles <= 358 * DEG)
        assert residuals[keep].min() > 0.01
    else:
        assert rotational_symmetry_residual(outline, sym) < 1e-6
        steps = angles / sym
        near_multiple = np.abs(steps - np.round(steps)) * sym <= 1.0 * DEG + 1e-9
        assert residuals[~near_multiple].min() > 0.01
        # and the symmetry is not a finer one (e.g. a square marked as a rectangle)
        assert rotational_symmetry_residual(outline, sym / 2) > 0.01


def test_residual_is_a_real_measure():
    square = box(-1, -1, 1, 1)
    assert rotational_symmetry_residual(square, math.pi / 2) < 1e-12
    # square vs itself at 45 degrees: they share a regular octagon of area 8(sqrt2 - 1)
    assert rotational_symmetry_residual(square, math.pi / 4) == pytest.approx(6 - 4 * math.sqrt(2), rel=1e-9)
    off_centre = box(0, 0, 2, 2)  # same square, not centred: rotating about the origin moves it
    assert rotational_symmetry_residual(off_centre, math.pi / 2) > 1.9


# --------------------------------------------------------------------------- size, grasp, thickness


@pytest.mark.parametrize("shape_id", SHAPE_IDS)
def test_footprint_and_frame(shape_id):
    g = shape_geometry(shape_id)
    pts = shapely.get_coordinates(g.outline)
    diameter = np.linalg.norm(pts[:, None] - pts[None], axis=2).max()
    assert diameter <= 0.06  # fits a 6 cm footprint at any yaw
    assert 0.015 <= g.footprint_radius <= 0.031
    assert g.footprint_radius == pytest.approx(np.linalg.norm(pts, axis=1).max())
    # origin is the area centroid (= rotation centre of symmetric shapes)
    assert abs(g.outline.centroid.x) < 1e-9 and abs(g.outline.centroid.y) < 1e-9
    assert g.height == SHAPE_HEIGHT == 0.03
    assert g.outline.is_valid and g.outline.exterior.is_ccw


@pytest.mark.parametrize("shape_id", SHAPE_IDS)
def test_graspable_across_some_direction(shape_id):
    g = shape_geometry(shape_id)
    assert g.grasp_width >= 0.008  # the Panda's upper bound is checked with the robot, in test_kit_physics.py
    assert grasp_width(shape_id, g.grasp_angle) == pytest.approx(g.grasp_width)
    # narrowest over a finer grid is not much narrower than the reported one
    fine = min(grasp_width(shape_id, t) for t in np.linspace(0, math.pi, 61))
    assert g.grasp_width <= fine + 0.002
    # grasp_width is direction-only: theta and theta + pi close the same fingers
    assert grasp_width(shape_id, 0.3) == pytest.approx(grasp_width(shape_id, 0.3 + math.pi))


def test_grasp_width_on_known_shapes():
    assert grasp_width(6, 0.0) == pytest.approx(0.050)  # rectangle 50 x 24 mm along its length
    assert grasp_width(6, math.pi / 2) == pytest.approx(0.024)
    assert grasp_width(11, 1.0) == pytest.approx(0.040, abs=2e-4)  # disc, any direction
    assert grasp_width(16, 0.0) == pytest.approx(0.042)  # ring: across the outer rim
    # a pad strip offset well beyond the shape touches nothing
    assert grasp_width(3, 0.0, center=(0.0, 0.2)) == 0.0


def test_grasp_width_takes_the_pad_width():
    # square 36 x 36 mm, pads centred 25 mm off its axis: 18 mm pads reach its edge at 18 mm, 4 mm pads do not
    assert grasp_width(3, 0.0, pad_width=0.018, center=(0.0, 0.025)) == pytest.approx(0.036)
    assert grasp_width(3, 0.0, pad_width=0.004, center=(0.0, 0.025)) == 0.0
    outline = shape_geometry(3).outline
    assert grasp_width_at(outline, 0.4) == grasp_width_at(outline, 0.4, pad_width=DEFAULT_PAD_WIDTH)
    assert DEFAULT_PAD_WIDTH == 0.018
    # the cached narrowest grasp is the default pads'; other pads are computed on request
    g = shape_geometry(0)
    assert narrowest_grasp(0) == (g.grasp_angle, g.grasp_width)
    theta, width = narrowest_grasp(0, pad_width=0.002)
    assert width == pytest.approx(grasp_width(0, theta, pad_width=0.002))
    assert width <= g.grasp_width + 1e-12


@pytest.mark.parametrize("shape_id", SHAPE_IDS)
def test_no_thin_parts(shape_id):
    assert min_thickness(shape_id) >= 0.008
    outline = shape_geometry(shape_id).outline
    eroded = outline.buffer(-0.0035)
    # a neck thinner than 7 mm would split the shape (or open the ring) under erosion
    assert isinstance(eroded, Polygon) and len(eroded.interiors) == len(outline.interiors)


def test_shapes_are_distinct():
    sig = {(round(g.area * 1e6), round(g.outline.length * 1e4)) for g in map(shape_geometry, SHAPE_IDS)}
    assert len(sig) == NUM_SHAPES
    assert len(shape_geometry(16).outline.interiors) == 1  # the ring really has a hole
    assert all(len(shape_geometry(i).outline.interiors) == 0 for i in SHAPE_IDS if i != 16)


@pytest.mark.parametrize("bad", [-1, 20, 25, 1.0, "3", None, True])
def test_bad_shape_id(bad):
    with pytest.raises(ValueError, match=r"0\.\.19") as e:
        shape_geometry(bad)
    assert repr(bad) in str(e.value) or str(bad) in str(e.value)
    with pytest.raises(ValueError):
        slot_outline(bad)


# --------------------------------------------------------------------------- collision and visual


@pytest.mark.parametrize("shape_id", SHAPE_IDS)
def test_convex_pieces_are_exact(shape_id):
    g = shape_geometry(shape_id)
    assert 1 <= len(g.convex_pieces) <= 24
    footprints = [_prism_is_convex_and_exact(p, 0.0, SHAPE_HEIGHT) for p in g.convex_pieces]
    _assert_exact_partition(footprints, g.outline, rel=1e-6)


@pytest.mark.parametrize("shape_id", SHAPE_IDS)
def test_generic_decomposition_of_outline(shape_id):
    """Hertel-Mehlhorn on the outline (the ring exercises holes) is an exact convex partition."""
    outline = shape_geometry(shape_id).outline
    parts = convex_decompose(outline)
    assert all(is_convex_polygon(p) for p in parts)
    _assert_exact_partition([Polygon(p) for p in parts], outline, rel=1e-9)


@pytest.mark.parametrize("shape_id", SHAPE_IDS)
def test_visual_mesh_is_closed_extrusion(shape_id):
    g = shape_geometry(shape_id)
    v, f = g.visual_vertices, g.visual_faces
    assert v.dtype == np.float32 and v.shape[1] == 3 and f.dtype == np.int32 and f.shape[1] == 3
    assert f.min() >= 0 and f.max() < len(v)
    assert v[:, 2].min() == 0.0 and v[:, 2].max() == pytest.approx(SHAPE_HEIGHT)
    # positive signed volume = closed and outward-facing
    assert mesh_volume(v, f) == pytest.approx(g.area * SHAPE_HEIGHT, rel=1e-5)


def test_convex_helpers_reject_non_convex():
    l_shape = np.array([[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]], float)
    assert not is_convex_polygon(l_shape)
    assert not is_convex_polygon(l_shape[::-1])  # clockwise is not accepted either
    assert is_convex_polygon(np.array([[0, 0], [1, 0], [2, 0], [1, 1]], float))  # collinear point is fine
    frame = box(0, 0, 3, 3).difference(box(1, 1, 2, 2))
    parts = convex_decompose(frame)
    assert len(parts) >= 4 and all(is_convex_polygon(p) for p in parts)
    _assert_exact_partition([Polygon(p) for p in parts], frame, rel=1e-12)
    prism = extrude_convex(np.array([[0, 0], [1, 0], [0, 1]]), 0.5, 1.5)
    assert prism.shape == (6, 3) and prism.dtype == np.float32


# --------------------------------------------------------------------------- slots


@pytest.mark.parametrize("shape_id", SHAPE_IDS)
@pytest.mark.parametrize("clearance", [0.002, 0.004])
def test_slot_outline_is_shape_plus_clearance(shape_id, clearance):
    outline = shape_geometry(shape_id).outline
    solid = Polygon(outline.exterior)
    slot = slot_outline(shape_id, clearance)
    assert len(slot.interiors) == 0  # the ring's slot is its outer disc
    assert slot.contains(solid.buffer(clearance * 0.999))  # at least the clearance everywhere...
    assert slot.exterior.distance(solid) == pytest.approx(clearance, rel=1e-6)  # ...and exactly it on the sides
    expected = solid.buffer(clearance, join_style="mitre", mitre_limit=MITRE_LIMIT)
    assert slot.area == pytest.approx(expected.area, rel=1e-12)
    # mitred, not bevelled or rounded: strictly more area than the round offset
    assert slot.area > solid.buffer(clearance, quad_segs=64).area
    assert slot_outline(shape_id, 0.0).symmetric_difference(solid).area < 1e-15


def test_slot_placement_follows_yaw():
    slot = slot_outline(6)  # rectangle, long axis along x, with its own clearance
    c = SLOT_CLEARANCE[6]
    placed = place(slot, 0.01, -0.02, math.pi / 2)
    minx, miny, maxx, maxy = placed.bounds
    assert (maxx - minx) == pytest.approx(0.024 + 2 * c) and (maxy - miny) == pytest.approx(0.050 + 2 * c)
    assert placed.centroid.x == pytest.approx(0.01) and placed.centroid.y == pytest.approx(-0.02)


# --------------------------------------------------------------------------- board

TYPICAL_KIT = [(0, 0.045, -0.085, 0.3), (3, 0.045, 0.0, 1.0), (5, 0.045, 0.085, 2.0),
               (7, -0.045, -0.045, 0.5), (13, -0.045, 0.045, -1.2)]  # fmt: skip
ROUND_KIT = [(11, 0.045, -0.085, 0.3), (16, 0.045, 0.0, 1.0), (10, 0.045, 0.085, 2.0),
             (9, -0.045, -0.045, 0.5), (19, -0.045, 0.045, -1.2)]  # fmt: skip


@pytest.mark.parametrize("slots", [TYPICAL_KIT, ROUND_KIT], ids=["typical", "disc_and_ring"])
def test_board_pieces_are_exact(slots):
    b = board_geometry(slots)
    assert b.floor == SLOT_FLOOR == 0.01 and b.top == 0.02 and b.size == BOARD_SIZE
    slab = _prism_is_convex_and_exact(b.convex_pieces[0], 0.0, SLOT_FLOOR)
    assert slab.area == pytest.approx(0.20 * 0.28)
    tops = [_prism_is_convex_and_exact(p, SLOT_FLOOR, SLOT_FLOOR + POCKET_DEPTH) for p in b.convex_pieces[1:]]
    _assert_exact_partition(tops, b.top_polygon, rel=1e-6)  # float32 vertices
    assert len(b.top_convex_polygons) == len(tops)
    _assert_exact_partition([Polygon(p) for p in b.top_convex_polygons], b.top_polygon, rel=1e-9)  # float64
    expected_area = 0.20 * 0.28 - sum(slot_outline(s[0]).area for s in slots)
    assert b.top_polygon.area == pytest.approx(expected_area, rel=1e-9)
    assert len(b.slot_polygons) == 5 and len(b.top_polygon.interiors) == 5
    assert len(b.convex_pieces) <= (40 if slots is TYPICAL_KIT else 120)
    assert mesh_volume(b.visual_vertices, b.visual_faces) == pytest.approx(
        0.20 * 0.28 * SLOT_FLOOR + b.top_polygon.area * POCKET_DEPTH, rel=1e-5
    )


@pytest.mark.parametrize("slots", [TYPICAL_KIT, ROUND_KIT], ids=["typical", "disc_and_ring"])
def test_board_collision_mesh_is_its_closed_surface(slots):
    """What PhysX collides with: one welded, closed, outward-facing mesh of the board's surface, every pocket a
    wall ring down to a floor, no internal faces (the convex pieces' internal faces are what misled the contact
    generation: kits/board.py)."""
    b = board_geometry(slots)
    v, f = b.collision_mesh
    assert v.dtype == np.float32 and f.dtype == np.int32 and f.min() >= 0 and f.max() < len(v)
    assert len(np.unique(np.round(v.astype(np.float64), 9), axis=0)) == len(v)  # welded
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    assert len({tuple(e) for e in directed.tolist()}) == len(directed)  # each directed edge once: consistent winding
    _, count = np.unique(np.sort(directed, axis=1), axis=0, return_counts=True)
    assert set(count.tolist()) == {2}  # closed
    assert mesh_volume(v, f) == pytest.approx(0.20 * 0.28 * SLOT_FLOOR + b.top_polygon.area * POCKET_DEPTH, rel=1e-6)
    assert sorted(set(np.round(v[:, 2], 7).tolist())) == pytest.approx([0.0, SLOT_FLOOR, SLOT_FLOOR + POCKET_DEPTH])


def test_board_clearance_forms():
    """None: every shape its own; one number: every pocket; a sequence: one per shape id."""
    assert pocket_clearances(None) == SLOT_CLEARANCE
    assert pocket_clearances(0.003) == (0.003,) * NUM_SHAPES
    assert pocket_clearances(list(SLOT_CLEARANCE)) == SLOT_CLEARANCE
    with pytest.raises(ValueError, match="one clearance per shape id"):
        pocket_clearances([0.001, 0.002])
    with pytest.raises(ValueError, match=">= 0"):
        pocket_clearances(-0.001)
    b = board_geometry(TYPICAL_KIT)
    for (sid, x, y, yaw), poly in zip(TYPICAL_KIT, b.slot_polygons, strict=True):
        assert poly.equals_exact(place(slot_outline(sid, SLOT_CLEARANCE[sid]), x, y, yaw), 1e-12)


def test_board_slot_polygons_are_placed_slots():
    b = board_geometry(TYPICAL_KIT, clearance=0.003)
    for (sid, x, y, yaw), poly in zip(TYPICAL_KIT, b.slot_polygons, strict=True):
        assert poly.equals_exact(place(slot_outline(sid, 0.003), x, y, yaw), 1e-12)
        # a shape seated at the slot pose fits inside its pocket with the clearance all round
        seated = place(shape_geometry(sid).outline, x, y, yaw)
        assert poly.contains(seated.buffer(0.0029))


def test_board_rejects_bad_layouts():
    with pytest.raises(ValueError, match="overlaps slot 0"):
        board_geometry([(0, 0.0, 0.0, 0.0), (3, 0.01, 0.0, 0.0)])
    with pytest.raises(ValueError, match="outside the board"):
        board_geometry([(0, 0.09, 0.0, 0.0)])


def _caliper_width(pts: np.ndarray) -> float:
    """Smallest extent of a convex polygon over its edge normals (its minimum width)."""
    pts = np.asarray(pts, dtype=np.float64)
    edges = np.roll(pts, -1, axis=0) - pts
    normals = np.column_stack([-edges[:, 1], edges[:, 0]]) / np.linalg.norm(edges, axis=1)[:, None]
    extents = (pts @ normals.T).max(axis=0) - (pts @ normals.T).min(axis=0)
    return float(extents.min())


def test_default_boards_have_no_sliver_pieces():
    """Slivers are what PhysX cooks and collides worst; the constrained Delaunay triangulation keeps the
    thinnest piece of the 300 default boards at 0.42 mm (ear clipping made 0.05 mm ones)."""
    from kitbench.kits import load_episodes

    episodes = load_episodes(None)
    thinnest = min(
        _caliper_width(p) for i in range(len(episodes)) for p in episodes.board_geometry(i).top_convex_polygons
    )
    assert thinnest > 0.0003


def test_shape_pieces_are_about_a_centimetre_wide_or_more():
    """Narrow pieces (the ring's sectors were 5.4 mm) make PhysX misjudge contacts with the pocket walls."""
    widths = {i: min(_caliper_width(p) for p in shape_geometry(i).convex_polygons) for i in SHAPE_IDS}
    assert min(widths.values()) > 0.0099, widths


@pytest.mark.parametrize("shape_id", [i for i in SHAPE_IDS if SYMMETRY[i] == TWO_PI])
def test_turned_ten_degrees_an_asymmetric_shape_fits_its_slot_nowhere(shape_id):
    """Geometry behind the 4-degree rule: at 10 degrees off no shift within the clearance lets it in, at 1
    degree it fits centred."""
    outline, slot = shape_geometry(shape_id).outline, slot_outline(shape_id)
    shifts = np.linspace(-0.002, 0.002, 9)
    for dyaw in (10 * DEG, -10 * DEG):
        assert not any(slot.contains(place(outline, dx, dy, dyaw)) for dx in shifts for dy in shifts)
    assert slot.contains(place(outline, 0.0, 0.0, DEG)) and slot.contains(place(outline, 0.0, 0.0, -DEG))


def test_package_type_checking_imports_match_the_lazy_exports():
    """kitbench.kits re-exports lazily; the names type checkers see are listed separately and must agree."""
    tree = ast.parse(Path(kits.__file__).read_text(encoding="utf-8"))
    block = next(n for n in tree.body if isinstance(n, ast.If) and ast.unparse(n.test) == "TYPE_CHECKING")
    seen = {
        alias.name: node.module.rsplit(".", 1)[1]
        for node in block.body
        if isinstance(node, ast.ImportFrom) and node.module
        for alias in node.names
    }
    assert seen == kits._EXPORTS
    assert all(getattr(kits, name) is not None for name in kits.__all__)
