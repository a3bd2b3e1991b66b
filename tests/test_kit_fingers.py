"""Where the open fingertips come down around a shape and how clear of obstacles they are (pure geometry, no
simulator): what the expert chooses its grasp by and studies/assembling_kits_grasp/grasp_misses.py measures a policy's
grasps by."""

from __future__ import annotations

import math

import pytest
from shapely.geometry import Point, box

from kitbench.kits import load_episodes
from kitbench.kits.fingers import (
    FINGER_THICKNESS,
    FINGERTIP_CENTER,
    finger_footprints,
    fingertip_clearance,
    pick_obstacles,
    seated_outlines,
)

OUTER = FINGERTIP_CENTER + FINGER_THICKNESS / 2  # a fingertip's far edge from the grasp centre


def test_fingertips_come_down_on_both_sides_along_the_closing_direction():
    pads = finger_footprints((0.0, 0.0), 0.0)
    xs = sorted(p.centroid.x for p in pads)
    assert xs == pytest.approx([-FINGERTIP_CENTER, FINGERTIP_CENTER], abs=1e-9)
    assert all(abs(p.centroid.y) < 1e-9 for p in pads)
    swept = finger_footprints((0.0, 0.0), math.pi / 2, swept=True)  # in to the centre while they close
    assert all(p.bounds[0] > -0.01 and p.bounds[2] < 0.01 for p in swept)
    assert min(abs(p.bounds[1]) for p in swept) == pytest.approx(0.0, abs=1e-9)


def test_an_obstacle_on_one_side_blocks_the_directions_pointing_at_it_and_no_others():
    wall = box(OUTER - 0.005, -0.01, OUTER + 0.02, 0.01)  # reaches 5 mm inside the fingertips' reach along +x
    assert fingertip_clearance((0.0, 0.0), 0.0, [wall]) == 0.0  # closing along x: a fingertip lands on it
    assert fingertip_clearance((0.0, 0.0), math.pi, [wall]) == 0.0  # the same direction, the hand turned round
    assert fingertip_clearance((0.0, 0.0), math.pi / 2, [wall]) > 0.02  # along y: well clear
    assert fingertip_clearance((-0.009, 0.0), 0.0, [wall]) == pytest.approx(0.004, abs=1e-9)
    assert fingertip_clearance((0.0, 0.0), 0.0, []) == 1.0  # nothing around


def test_pick_obstacles_are_the_board_edge_on_the_table_and_the_seated_shapes_on_the_board():
    episodes = load_episodes()
    episode = next(e for e in episodes.episodes if len(e.obj_in_place) >= 2)
    board = episodes.board
    (edge,) = pick_obstacles(episode, board, shape_z=0.001)
    assert edge.bounds == pytest.approx((-board.size[0] / 2, -board.size[1] / 2, board.size[0] / 2, board.size[1] / 2))
    seated = pick_obstacles(episode, board, shape_z=board.top + 0.001)
    assert len(seated) == len(episode.obj_in_place) == len(seated_outlines(episode))
    for outline, i in zip(seated, episode.obj_in_place, strict=True):
        assert outline.centroid.distance(Point(*episode.slots[i].pos[:2])) < 0.02  # placed at its slot


def test_another_hands_pads_lie_along_its_closing_direction_from_its_tcp():
    pads = ((-0.026, 0.0, 0.0115), (0.0, 0.05, 0.011))  # a fixed jaw behind the TCP, a moving one ahead
    fixed, moving = finger_footprints((0.1, 0.2), 0.0, pads=pads)
    assert fixed.bounds == pytest.approx((0.074, 0.1885, 0.1, 0.2115))
    assert moving.bounds == pytest.approx((0.1, 0.189, 0.15, 0.211))
    fixed, _ = finger_footprints((0.0, 0.0), math.pi / 2, pads=pads)  # turned: the fixed jaw now behind along -y
    assert fixed.bounds == pytest.approx((-0.0115, -0.026, 0.0115, 0.0), abs=1e-12)
    wall = box(-0.1, -0.1, -0.04, 0.1)
    assert fingertip_clearance((0.0, 0.0), 0.0, [wall], pads=pads) == pytest.approx(0.014)
    assert fingertip_clearance((0.0, 0.0), math.pi, [wall], pads=pads) == pytest.approx(0.0)
