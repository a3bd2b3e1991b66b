"""bench/camera_view.py: what the observation cameras see of a task along its expert's episodes, counted from the
segmentation they render."""

from __future__ import annotations

import pytest

from bench.camera_view import main, measure, summarize


@pytest.fixture(scope="module")
def kits():
    return measure("AssemblingKits-v1", [1000000], camera_size="32", control_mode="pd_ee_delta_pose")


def _row(rows, phase, camera):
    return next(r for r in rows if r["phase"] == phase and r["camera"] == camera)


def test_every_phase_is_counted_once_per_camera_in_the_experts_order(kits):
    from kitbench.planning.assembling_kits import AssemblingKitsPlanner

    assert kits["camera_size"] == "32x32" and kits["target_object"] == "obj_to_place"
    phases = list(kits["phases"])
    assert phases == sorted(phases, key=AssemblingKitsPlanner.phases.index)
    for cameras in kits["phases"].values():
        assert set(cameras) == {"base_camera", "hand_camera"}
        assert cameras["base_camera"]["frames"] == cameras["hand_camera"]["frames"] > 0


def test_the_counts_follow_the_scene(kits):
    rows = summarize(kits)
    base = [r for r in rows if r["camera"] == "base_camera"]
    # the fixed camera frames the whole board: the slot projects into it all episode long
    assert all(r["in_view"]["goal"] == 1.0 for r in base)
    # the hand closing on the shape fills its wrist camera with it
    assert _row(rows, "grasp", "hand_camera")["object_px"] > 4 * _row(rows, "approach", "hand_camera")["object_px"]
    # while the shape goes into the slot it hides the slot from the fixed camera, not from view
    insert = _row(rows, "insert", "base_camera")
    assert insert["seen"]["goal"] < insert["in_view"]["goal"]
    assert all(0.0 <= r["seen"][k] <= r["in_view"][k] <= 1.0 for r in rows for k in r["in_view"])


def test_a_task_tracking_only_its_object_counts_its_pixels():
    rows = summarize(measure("LiftPegUpright-v1", [0], camera_size="32"))
    assert rows and all(r["in_view"] == {} for r in rows)
    assert _row(rows, "approach", "base_camera")["object_px"] > 0
    # ManiSkill's wide framing keeps the whole peg inside the picture; the lowered arm hides it in few frames
    assert all(r["cut"] == 0.0 and 0.0 <= r["hidden"] < 0.5 for r in rows)


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["--task", "AssemblingKits-v1", "--camera-size", "3x"], "camera_size must be WIDTHxHEIGHT"),
        (["--task", "Nope-v1"], "Nope-v1"),
        (["--task", "LiftPegUpright-v1", "--seeds", "0:0"], "--seeds '0:0' must be"),
    ],
)
def test_bad_arguments_are_one_line(argv, needle, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("camera_view: error:") and needle in err
