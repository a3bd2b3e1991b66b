"""studies/set_down/peg_release.py: where a LiftPegUpright policy holds the peg and how it lets it go, seed by seed."""

from __future__ import annotations

import pytest

from studies.set_down.peg_release import main, measure, play


def test_the_so101_expert_holds_the_peg_where_its_config_says_and_stands_it_up_held():
    rows, robot = measure("expert", [0, 1], "so101", {})
    assert robot == "so101"
    for row in rows:
        # grasp_offset 0.3 of the 6 cm half-length: 18 mm out from the centre
        assert row["along_mm"] == pytest.approx(18.0, abs=2.0)
        assert row["success"] and row["lost"] is None
        # the swing ends with the peg 2 mm above the table (set_down_clearance), upright in the hand
        assert row["upright"]["above_mm"] == pytest.approx(2.0, abs=2.0)
        assert row["upright"]["hand_deg"] < 5.0


def test_the_height_the_peg_is_held_upright_at_follows_the_experts_set_down_clearance():
    rows, _ = measure("expert", [0, 1], "so101", {"set_down_clearance": 0.015})
    for row in rows:
        assert row["upright"]["above_mm"] == pytest.approx(14.0, abs=2.5)
        assert row["upright"]["hand_deg"] < 3.0 and row["success"]


def test_a_hand_opened_mid_swing_reads_as_let_go_while_the_peg_leans():
    from kitbench.registration import make_env
    from tests.test_evaluation import _LetGoMidSwing

    env = make_env("LiftPegUpright-v1", control_mode="pd_joint_pos")
    try:
        row = play(env, _LetGoMidSwing("open"), 1)
    finally:
        env.close()
    assert not row["success"] and row["lost"]["let_go"]
    assert row["lost"]["tilt_deg"] > 10.0  # four steps into the swing the peg is still far from upright
    # the tilt is mostly the hand's: the swing had turned it a few steps, the peg had turned little in the grip
    assert row["lost"]["hand_deg"] > 10.0 and row["lost"]["in_hand_deg"] < row["lost"]["hand_deg"] / 4


def test_bad_seeds_are_one_line(capsys):
    assert main(["--policy", "expert", "--seeds", "a:b"]) == 2
    err = capsys.readouterr().err
    assert "--seeds 'a:b' must be a count N, a range A:B of seeds >= 0" in err and err.count("\n") == 1
