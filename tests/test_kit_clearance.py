"""Pocket clearance per shape (kitbench.kits.clearance): the largest yaw at which a shape fits its pocket, computed
from the outline, stays below the success test's 4 degrees (pure geometry; tests/test_kit_physics.py checks the
same limit in PhysX)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from kitbench.kits.clearance import (
    CLEARANCE_STEP,
    DEFAULT_CLEARANCE,
    MAX_MODELLED_YAW,
    MAX_SEATED_YAW,
    SLOT_CLEARANCE,
    SUCCESS_YAW_TOLERANCE,
    clearance_for_yaw,
    max_seated_yaw,
    required_clearance,
)
from kitbench.kits.shapes import NUM_SHAPES, SYMMETRY, place, shape_outline, slot_outline
from kitbench.tasks.assembling_kits import ROT_TOLERANCE

DEG = math.pi / 180
TURNING = [i for i in range(NUM_SHAPES) if SYMMETRY[i] > 0]  # the disc and the ring fit at any yaw


def test_the_seated_yaw_leaves_a_margin_below_the_success_tolerance():
    assert SUCCESS_YAW_TOLERANCE == pytest.approx(ROT_TOLERANCE)
    assert MAX_SEATED_YAW == pytest.approx(3.5 * DEG)


@pytest.mark.parametrize("shape_id", range(NUM_SHAPES))
def test_the_table_is_the_clearance_for_the_largest_seated_yaw(shape_id):
    if SYMMETRY[shape_id] <= 0:
        assert SLOT_CLEARANCE[shape_id] == DEFAULT_CLEARANCE
        return
    assert SLOT_CLEARANCE[shape_id] == pytest.approx(clearance_for_yaw(shape_outline(shape_id)), abs=1e-12)
    # whole steps of 0.01 mm, as an episode file writes them
    assert SLOT_CLEARANCE[shape_id] / CLEARANCE_STEP == pytest.approx(round(SLOT_CLEARANCE[shape_id] / CLEARANCE_STEP))


@pytest.mark.parametrize("shape_id", TURNING)
def test_in_its_pocket_a_shape_turns_at_most_the_seated_yaw(shape_id):
    outline = shape_outline(shape_id)
    limit = min(MAX_MODELLED_YAW, SYMMETRY[shape_id] / 2)
    # each sense of rotation: a chiral shape may turn further one way
    ccw, cw = (max_seated_yaw(outline, SLOT_CLEARANCE[shape_id], limit, sense) for sense in (1.0, -1.0))
    assert ccw <= MAX_SEATED_YAW and cw <= MAX_SEATED_YAW
    assert MAX_SEATED_YAW - 0.2 * DEG < max(ccw, cw)


@pytest.mark.parametrize("shape_id", TURNING)
def test_needed_clearance_grows_with_the_yaw_up_to_the_modelled_range(shape_id):
    """max_seated_yaw bisects on this, and a pocket that stops a shape at 3.5 degrees stops it further on too."""
    outline = shape_outline(shape_id)
    top = min(MAX_MODELLED_YAW, SYMMETRY[shape_id] / 2)
    yaws = np.arange(0.25 * DEG, top, 0.25 * DEG)
    for sense in (1.0, -1.0):
        needed = [required_clearance(outline, sense * y)[0] for y in yaws]
        assert all(b > a for a, b in itertools.pairwise(needed)), (sense, needed)


@pytest.mark.parametrize("shape_id", TURNING)
@pytest.mark.parametrize("yaw_deg", [1.0, 2.0, 3.5, -3.5])
def test_the_linear_programme_agrees_with_polygon_containment(shape_id, yaw_deg):
    """At the clearance it computes, its shift fits the turned shape in the pocket; 5 micrometres less and no
    shift within half a millimetre of it does."""
    outline = shape_outline(shape_id)
    yaw = yaw_deg * DEG
    clearance, (dx, dy) = required_clearance(outline, yaw)
    assert slot_outline(shape_id, clearance + 1e-7).contains(place(outline, dx, dy, yaw))
    tight = slot_outline(shape_id, clearance - 5e-6)
    shifts = np.linspace(-0.0005, 0.0005, 21)
    assert not any(tight.contains(place(outline, dx + sx, dy + sy, yaw)) for sx in shifts for sy in shifts)


REGULAR = [(3, 4, 0.018 * math.sqrt(2)), (7, 5, 0.023), (17, 6, 0.024), (2, 3, 0.044 / math.sqrt(3))]


@pytest.mark.parametrize(("shape_id", "sides", "circumradius"), REGULAR)
def test_regular_polygons_need_the_closed_form_clearance(shape_id, sides, circumradius):
    """A regular n-gon turned by yaw about its centre reaches R cos(pi/n - yaw) along an edge normal, against the
    pocket's R cos(pi/n) + c; centred is its best shift by symmetry. The more sides, the less clearance a turn
    needs: the hexagon's pocket is the tightest."""
    outline = shape_outline(shape_id)
    for yaw in (0.5 * DEG, 2 * DEG, 3.5 * DEG, 8 * DEG):
        expected = circumradius * (math.cos(math.pi / sides - yaw) - math.cos(math.pi / sides))
        assert required_clearance(outline, yaw)[0] == pytest.approx(expected, abs=1e-9)
        assert required_clearance(outline, -yaw)[0] == pytest.approx(expected, abs=1e-9)


@pytest.mark.parametrize("shape_id", TURNING)
def test_at_the_old_two_millimetres_every_shape_fits_past_the_tolerance(shape_id):
    """Why the clearance is per shape: with 2 mm everywhere every shape fits its pocket more than 4 degrees off,
    from the four-pointed star (4.5 degrees) to the hexagon (11.7)."""
    limit = min(MAX_MODELLED_YAW, SYMMETRY[shape_id] / 2)
    assert max_seated_yaw(shape_outline(shape_id), DEFAULT_CLEARANCE, limit) > SUCCESS_YAW_TOLERANCE
