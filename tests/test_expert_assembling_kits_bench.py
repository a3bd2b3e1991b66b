"""bench/expert_assembling_kits.py's `--misread`: the expert reading its slot wrong places the shape where it read
it, and the success test, which reads the true slot, fails it."""

from __future__ import annotations

import argparse
import math

import numpy as np
import pytest

from bench.expert_assembling_kits import misread_of, parse_misread, run_seeds

SEED = 1  # a hexagon: its yaw matters, and the expert seats it when it reads the slot right


def _episode(misread):
    (episode,) = run_seeds(([SEED], "pd_joint_pos", "panda_wristcam", {}, misread))
    return episode


def test_the_expert_seats_the_shape_where_it_reads_the_slot():
    assert _episode((0.0, 0.0)).success
    shifted = _episode((4.0, 0.0))  # beyond every pocket's 0.69-2 mm clearance
    assert not shifted.success and shifted.category in ("not inserted", "jammed at the slot")
    turned = _episode((0.0, 10.0))  # beyond the 4-degree test and the 3.5 degrees a pocket lets a shape turn
    assert not turned.success


def test_each_seed_draws_its_own_direction_and_every_row_the_same_one():
    shift, turn = misread_of(SEED, (2.0, 3.0))
    assert math.isclose(float(np.linalg.norm(shift)), 0.002) and math.isclose(abs(turn), math.radians(3.0))
    again, turn_again = misread_of(SEED, (1.0, 3.0))
    assert np.allclose(again * 2.0, shift) and turn_again == turn
    directions = {tuple(np.round(misread_of(seed, (1.0, 1.0))[0], 6)) for seed in range(20)}
    assert len(directions) == 20


@pytest.mark.parametrize("text", ["1.5", "a,b", "-1,2", "1,2,3"])
def test_a_bad_misread_names_the_form(text):
    with pytest.raises(argparse.ArgumentTypeError, match="--misread wants MM,DEG"):
        parse_misread(text)
