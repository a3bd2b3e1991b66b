"""A kit built smaller for a smaller hand (`EpisodeSet.scaled`, `shape_geometry(id, scale)`): every dimension of the
shapes, pockets and board scaled, the pockets' clearances with them so that each shape keeps its largest seated yaw,
the standard kit unchanged, and a bad scale refused in one line."""

from __future__ import annotations

import numpy as np
import pytest
from shapely import affinity

from kitbench.errors import KitbenchError
from kitbench.kits import NUM_SHAPES, load_episodes, shape_geometry, slot_outline, validate_episodes
from kitbench.kits.shapes import place

SCALE = 0.7


@pytest.mark.parametrize("shape_id", range(NUM_SHAPES))
def test_a_scaled_shape_and_its_pocket_are_the_standard_ones_scaled(shape_id):
    standard, small = shape_geometry(shape_id), shape_geometry(shape_id, SCALE)
    assert small.area == pytest.approx(SCALE**2 * standard.area, rel=1e-9)
    assert small.height == pytest.approx(SCALE * standard.height)
    assert small.footprint_radius == pytest.approx(SCALE * standard.footprint_radius)
    assert max(float(p[:, 2].max()) for p in small.convex_pieces) == pytest.approx(small.height)
    assert sum(_area(p) for p in small.convex_polygons) == pytest.approx(small.area, rel=1e-9)
    # the pocket, cut with the scaled clearance, is the standard pocket scaled: the same largest seated yaw
    expected = affinity.scale(slot_outline(shape_id), SCALE, SCALE, origin=(0.0, 0.0))
    assert slot_outline(shape_id, scale=SCALE).symmetric_difference(expected).area < 1e-10
    assert shape_geometry(shape_id, 1.0) is standard


def _area(polygon) -> float:
    x, y = polygon[:, 0], polygon[:, 1]
    return 0.5 * float(abs((x * np.roll(y, -1) - np.roll(x, -1) * y).sum()))


def test_a_scaled_episode_set_keeps_its_kits_and_survives_its_own_file():
    standard = load_episodes()
    small = standard.scaled(SCALE)
    assert standard.scaled(1.0) is standard and standard.board.scale == 1.0
    b = small.board
    assert b.scale == SCALE and b.top == pytest.approx(SCALE * standard.board.top)
    assert b.clearance == pytest.approx([SCALE * c for c in standard.board.clearance])
    for i in range(0, len(small), 15):  # every pocket still on the board and clear of the others
        geometry = small.board_geometry(i)
        for slot, polygon in zip(small[i].slots, geometry.slot_polygons, strict=True):
            shape = place(shape_geometry(slot.shape_id, SCALE).outline, slot.pos[0], slot.pos[1], slot.yaw)
            assert polygon.contains(shape)
        assert small.goal_pose(i)[0][2] == pytest.approx(b.floor)
    again = validate_episodes(small.to_dict(), source="scaled")
    assert again.board == small.board and again[7].slots == small[7].slots
    assert "scale" not in standard.to_dict()["board"]


@pytest.mark.parametrize("scale", [0, -0.5, 3.0, "big", True])
def test_a_bad_scale_is_one_line_naming_it(scale):
    with pytest.raises(KitbenchError, match=r"kit scale must be a number in \(0, 2\], got"):
        shape_geometry(0, scale)
    with pytest.raises(KitbenchError, match=r"kit scale must be a number in \(0, 2\], got"):
        load_episodes().scaled(scale)
