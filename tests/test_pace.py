"""A config's training pace: a step's seconds read from lerobot-train's own log, and the published minutes scaled by
it where a row keeps its step time (the reference workload otherwise)."""

from __future__ import annotations

import dataclasses

import pytest

from kitbench.published import load_published
from kitbench.reproduce import expectation
from kitbench.training.pace import step_seconds


def _window(step: str, update: float, data: float) -> str:
    return (
        f"INFO 2026-12-02 12:00:00 ot_train.py:412 step:{step} smpl:6K ep:30 epch:0.78 loss:0.412 grdn:12.301 "
        f"lr:1.0e-05 updt_s:{update:.3f} data_s:{data:.3f} smp/s:88\n"
    )


def test_a_step_is_lerobots_update_and_loading_the_median_over_windows_after_the_first(tmp_path):
    log = tmp_path / "train.log"
    log.write_text(
        "INFO 2026-12-02 11:59:50 ot_train.py:300 num_learnable_params=51597190 (52M)\n"
        + _window("200", 1.900, 0.400)  # the warm-up window: left out
        + _window("400", 0.350, 0.010)
        + _window("600", 0.900, 0.100)  # a slow window: the median does not follow it
        + _window("800", 0.340, 0.005)
        + "Training:  33%|###       | 800/2400 [04:52<09:44,  0.37s/it]\n"
    )
    assert step_seconds(log) == pytest.approx(0.36)
    # one window only: it is all there is
    log.write_text(_window("5", 0.5, 0.25))
    assert step_seconds(log) == pytest.approx(0.75)
    # no window (a training shorter than its log_freq), and no log at all
    log.write_text("Training:  100%|##########| 2/2\n")
    assert step_seconds(log) is None
    assert step_seconds(tmp_path / "missing.log") is None


def test_a_row_with_its_step_time_scales_by_the_step_here_and_says_so():
    row = dataclasses.replace(load_published()["act_lift_peg_upright_state"], step_seconds=None)
    timed = dataclasses.replace(row, step_seconds=0.05)
    # twice the published step here: twice the minutes, whatever the reference workload reads
    assert timed.train_minutes_here(1.0, None, 0.10) == pytest.approx(2 * row.train_minutes)
    assert timed.train_minutes_here(1.0, row.steps // 2, 0.10) == pytest.approx(row.train_minutes)
    assert expectation(timed, 1.0, 2, None, 0.10) == (
        f"expected training time: about {2 * row.train_minutes:.1f} min here for {row.steps} steps (a step 0.100 s "
        f"here, lerobot-train's own timing on 2 thread(s); published {row.train_minutes:.1f} min for {row.steps} on "
        f"{row.device} at 0.050 s a step)"
    )
    # without a step time here, or without one published, the reference workload scales it
    by_reference = 2 * row.train_minutes
    assert timed.train_minutes_here(2 * row.training_reference) == pytest.approx(by_reference)
    assert row.train_minutes_here(2 * row.training_reference, None, 0.10) == pytest.approx(by_reference)


def test_training_and_scoring_minutes_from_different_runs_scale_by_their_own_reference():
    from kitbench.figures import machine

    row = dataclasses.replace(
        load_published()["act_assembling_kits_state"], reference_seconds=2.0, train_reference_seconds=4.0
    )
    assert row.training_reference == 4.0
    # a machine whose reference reads 8.0 s: twice the training's reading, four times the scoring's
    assert row.train_minutes_here(8.0) == pytest.approx(2 * row.train_minutes)
    assert row.eval_minutes_here(8.0) == pytest.approx(4 * row.eval_minutes)
    assert "reference 4.0 s on 1 thread as it trained, 2.0 s as it scored" in machine(row)
    # one run for both: one reading, said once, scaling both
    same = dataclasses.replace(row, train_reference_seconds=None)
    assert same.train_minutes_here(8.0) == pytest.approx(4 * row.train_minutes)
    assert "reference 2.0 s on 1 thread;" in machine(same) and "as it scored" not in machine(same)


def test_a_camera_config_without_a_published_step_is_timed_and_its_steps_alone_are_said():
    from kitbench.shipped import ROOT
    from kitbench.training.pace import reference_misleads

    assert reference_misleads(ROOT / "policies" / "act_lift_peg_upright_rgb_96_cpu.json")
    assert not reference_misleads(ROOT / "policies" / "act_lift_peg_upright_state.json")
    row = dataclasses.replace(load_published()["act_lift_peg_upright_so101_rgb_96_cpu"], step_seconds=None)
    by_reference = row.train_minutes * 6.0 / row.training_reference
    assert expectation(row, 6.0, 2, None, 2.0) == (
        f"expected training time: its {row.steps} steps alone take about {row.steps * 2.0 / 60:.1f} min here (a step "
        f"2.000 s here, lerobot-train's own timing on 2 thread(s); published {row.train_minutes:.1f} min for "
        f"{row.steps} on {row.device} came without a step time; by the reference workload, "
        f"{row.training_reference:.1f} s there and 6.0 s here: about {by_reference:.1f} min)"
    )
