"""studies/assembling_kits_pixels/perception_probe.py: what an image policy's encoder can read of the AssemblingKits
slot from a recording's cameras, scored on held-out episodes."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from studies.assembling_kits_pixels.perception_probe import Recording, main, score, split

ROOT = Path(__file__).resolve().parents[1]


def _recording(symmetry: float) -> Recording:
    """Two frames of one episode whose kit's five slots lie 5 cm apart on a line; the shape goes into slot 2."""
    slots = np.array([[0.0, 0.05 * i] for i in range(5)])
    goal, yaw = slots[2], 0.0
    k = 2 * math.pi / symmetry if symmetry > 0 else 0.0
    # no turn left; the shape at yaw 0, in the hand at yaw 0, the hand over the slot at yaw 0
    row = [*goal, math.cos(k * yaw), math.sin(k * yaw), 0.1, -0.1, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0]
    return Recording(
        root=Path("."),
        cameras=("observation.images.base_camera",),
        image_shape=(3, 8, 8),
        camera_size="8x8",
        camera_view=None,
        targets=np.array([row, row], dtype=np.float32),
        episode_of=np.array([0, 0]),
        slots={0: slots},
        target_slot={0: 2},
        empty={0: 3},
        symmetry={0: symmetry},
    )


def _folded(yaw_deg: float, symmetry: float) -> list[float]:
    k = 2 * math.pi / symmetry
    return [math.cos(k * math.radians(yaw_deg)), math.sin(k * math.radians(yaw_deg))]


def test_the_slot_figures_measure_what_they_name():
    square = math.pi / 2  # a square fits every quarter turn
    recording = _recording(square)
    frames = np.array([0, 1])
    exact = score(recording, frames, recording.targets.astype(np.float64))
    assert exact["goal_mm"] == [0.0, 0.0] and exact["right_slot"] == 1.0 and exact["shape_mm"] == 0.0
    assert exact["yaw_deg"] == pytest.approx(0.0, abs=1e-6) and exact["yaw_within_4deg"] == 1.0
    # 2 cm off towards the next slot is still nearest the right one; 3 cm off is nearer the next
    near = np.array(
        [
            [0.0, 0.12, *_folded(90.0, square), 0.1, -0.1, *_folded(3.0, square), *_folded(0, square), 1, 0, 1, 0],
            [0.0, 0.13, *_folded(45.0, square), 0.1, -0.08, *_folded(-10.0, square), *_folded(0, square), 1, 0, 1, 0],
        ]
    )
    figures = score(recording, frames, near)
    assert figures["goal_mm"][0] == pytest.approx(25.0, abs=1e-3)
    assert figures["right_slot"] == 0.5
    # a quarter turn is the same fit for a square; an eighth is as far off as a square can be
    assert figures["yaw_deg"] == pytest.approx(22.5, abs=1e-3) and figures["yaw_within_4deg"] == 0.5
    assert figures["shape_mm"] == pytest.approx(10.0, abs=1e-3)
    # the turn still needed, folded as the yaw: 3 and 10 degrees off a shape already turned to fit
    assert figures["turn_deg"] == pytest.approx(6.5, abs=1e-3) and figures["turn_within_4deg"] == 0.5
    assert math.isnan(figures["turning_deg"])  # no frame has more than 4 degrees still to turn


def test_the_turning_figure_counts_only_frames_still_to_turn():
    square = math.pi / 2
    recording = _recording(square)
    still = recording.targets.copy()
    still[1, 6:8] = _folded(30.0, square)  # the second frame has 30 degrees still to turn
    recording = dataclasses.replace(recording, targets=still)
    predicted = still.astype(np.float64)
    predicted[:, 6:8] = [_folded(1.0, square), _folded(20.0, square)]
    figures = score(recording, np.array([0, 1]), predicted)
    assert figures["turning_deg"] == pytest.approx(10.0, abs=1e-3)
    assert figures["turn_deg"] == pytest.approx(5.5, abs=1e-3)


def test_the_carried_figures_count_only_frames_with_the_shape_up_in_the_hand_and_still_to_turn():
    from studies.assembling_kits_pixels.perception_probe import lifted_frames

    square = math.pi / 2
    recording = _recording(square)
    targets = np.repeat(recording.targets, 2, axis=0)  # four frames: on the table twice, then up in the hand twice
    targets[:, 6:8] = [_folded(30.0, square), _folded(30.0, square), _folded(30.0, square), _folded(2.0, square)]
    lifted = lifted_frames(np.array([0.02, 0.021, 0.05, 0.06]), np.zeros(4, dtype=int))
    assert lifted.tolist() == [False, False, True, True]
    recording = dataclasses.replace(recording, targets=targets, episode_of=np.zeros(4, dtype=int), lifted=lifted)
    predicted = targets.astype(np.float64)
    predicted[:, 6:8] = [_folded(40.0, square), _folded(40.0, square), _folded(33.0, square), _folded(0.0, square)]
    predicted[:, 10:12] = [_folded(0.0, square), _folded(0.0, square), _folded(6.0, square), _folded(9.0, square)]
    figures = score(recording, np.arange(4), predicted)
    assert figures["turning_deg"] == pytest.approx(10.0, abs=1e-3)  # the three frames still to turn
    # only the third is up in the hand with a turn still to make (the fourth is turned)
    assert figures["carried_turn_deg"] == pytest.approx(3.0, abs=1e-3)
    assert figures["carried_grip_deg"] == pytest.approx(6.0, abs=1e-3)


def test_the_over_the_slot_figure_counts_only_carried_frames_within_2_cm_of_the_slot_still_to_turn():
    square = math.pi / 2
    recording = _recording(square)
    targets = np.repeat(recording.targets, 2, axis=0)  # four frames, all up in the hand
    targets[:, 6:8] = [_folded(30.0, square), _folded(30.0, square), _folded(30.0, square), _folded(2.0, square)]
    # the shape 22 cm from its slot, then 1.5 cm, 2.5 cm, and 1 cm (turned there)
    targets[:, 4:6] = targets[:, 0:2] + np.array([[0.1, -0.2], [0.015, 0.0], [0.0, 0.025], [0.01, 0.0]])
    lifted = np.ones(4, dtype=bool)
    recording = dataclasses.replace(recording, targets=targets, episode_of=np.zeros(4, dtype=int), lifted=lifted)
    predicted = targets.astype(np.float64)
    predicted[:, 6:8] = [_folded(10.0, square), _folded(35.0, square), _folded(20.0, square), _folded(0.0, square)]
    figures = score(recording, np.arange(4), predicted)
    assert figures["over_slot_frames"] == 1  # the second: the first is far, the third 2.5 cm off, the fourth turned
    assert figures["over_slot_turn_deg"] == pytest.approx(5.0, abs=1e-3)
    assert figures["carried_turn_deg"] == pytest.approx(10.0, abs=1e-3)  # 20, 5 and 10 degrees off


def test_each_shapes_carried_mean_is_what_knowing_the_shape_gives_the_yaw_in_the_hand():
    from studies.assembling_kits_pixels.perception_probe import baselines

    square = math.pi / 2
    base = _recording(square)
    # two episodes of one shape, held at 20 degrees in the hand, each one frame on the table and two up in it
    targets = np.repeat(base.targets, 3, axis=0)
    targets[:, 6:8] = _folded(30.0, square)
    targets[:, 10:12] = [_folded(d, square) for d in (0.0, 20.0, 20.0, 0.0, 20.0, 20.0)]
    recording = dataclasses.replace(
        base,
        targets=targets,
        episode_of=np.array([0, 0, 0, 1, 1, 1]),
        lifted=np.array([False, True, True, False, True, True]),
        slots={0: base.slots[0], 1: base.slots[0]},
        target_slot={0: 2, 1: 2},
        empty={0: 3, 1: 3},
        symmetry={0: square, 1: square},
        shape_of={0: 4, 1: 4},
    )
    figures = baselines(recording, train=np.array([0, 1, 2]), held=np.array([3, 4, 5]))
    assert figures["shape_mean"]["carried_grip_deg"] == pytest.approx(0.0, abs=1e-3)
    assert figures["mean"]["carried_grip_deg"] > 5.0  # the mean over every frame, the one on the table too


def test_the_shape_yaw_and_its_yaw_in_the_hand_are_folded_by_its_symmetry():
    square = math.pi / 2
    recording = _recording(square)
    predicted = recording.targets.astype(np.float64)
    # the shape 90 degrees off is the same fit for a square, in the hand or out of it (a picture shows the same)
    predicted[0, 8:10] = _folded(90.0, square)
    predicted[0, 10:12] = _folded(90.0, square)
    # 5 degrees off the shape is 5 degrees; 45 off in the hand is as far as a square gets
    predicted[1, 8:10] = _folded(5.0, square)
    predicted[1, 10:12] = _folded(45.0, square)
    figures = score(recording, np.array([0, 1]), predicted)
    assert figures["shape_yaw_deg"] == pytest.approx(2.5, abs=1e-3) and figures["shape_yaw_within_4deg"] == 0.5
    assert figures["grip_deg"] == pytest.approx(22.5, abs=1e-3) and figures["grip_within_4deg"] == 0.5


@pytest.mark.parametrize(
    ("symmetry", "shape_deg", "hand_deg", "in_hand_deg"),
    [
        (math.pi / 2, 100.0, 10.0, 0.0),  # a square 90 degrees round in the hand sits as it did
        (math.pi / 2, 100.0, 30.0, -20.0),
        (2 * math.pi / 3, 50.0, -80.0, 10.0),  # a triangle: 130 less a third of a turn
        (2 * math.pi, 170.0, -20.0, -170.0),  # no symmetry: the whole turn counts
        (math.pi, 10.0, 180.0, 10.0),  # a half turn of the hand is none for a rectangle
    ],
)
def test_the_yaw_in_the_hand_is_the_shapes_less_the_hands_folded_by_its_symmetry(
    symmetry, shape_deg, hand_deg, in_hand_deg
):
    from studies.assembling_kits_pixels.perception_probe import in_hand_yaw

    hand = math.radians(hand_deg)
    got = in_hand_yaw(
        np.array([_folded(shape_deg, symmetry)]),
        np.array([[math.cos(hand), math.sin(hand)]]),
        np.array([2 * math.pi / symmetry]),
    )
    assert got[0] == pytest.approx(_folded(in_hand_deg, symmetry), abs=1e-6)
    # a disc or ring: any yaw fits, the target is constant
    assert in_hand_yaw(got, np.array([[0.0, 1.0]]), np.array([0.0]))[0] == pytest.approx([1.0, 0.0])


@pytest.mark.parametrize(
    ("symmetry", "slot_deg", "in_hand_deg", "hand_deg"),
    [
        (math.pi / 2, 30.0, 10.0, 20.0),  # a square held 10 degrees round sits in a 30-degree slot from 20
        (math.pi / 2, 40.0, -40.0, -10.0),  # 80 is a quarter turn less 10: the same fit for a square
        (2 * math.pi, 170.0, -20.0, -170.0),  # no symmetry: 190 is -170
        (math.pi, 10.0, 100.0, 90.0),  # -90 and 90 are the same hand for a rectangle
    ],
)
def test_the_hand_over_the_slot_is_the_slots_yaw_less_the_yaw_in_the_hand(symmetry, slot_deg, in_hand_deg, hand_deg):
    from studies.assembling_kits_pixels.perception_probe import hand_over_slot

    order = np.array([2 * math.pi / symmetry])
    got = hand_over_slot(np.array([_folded(slot_deg, symmetry)]), np.array([_folded(in_hand_deg, symmetry)]), order)
    assert got[0] == pytest.approx(_folded(hand_deg, symmetry), abs=1e-6)
    assert hand_over_slot(got, got, np.array([0.0]))[0] == pytest.approx([1.0, 0.0])  # a disc: any yaw fits


def test_the_hand_over_the_slot_is_scored_over_the_carried_frames_too():
    square = math.pi / 2
    recording = _recording(square)
    targets = recording.targets.copy()
    targets[:, 6:8] = _folded(30.0, square)  # both frames still to turn
    recording = dataclasses.replace(recording, targets=targets, lifted=np.array([False, True]))
    predicted = targets.astype(np.float64)
    predicted[:, 12:14] = [_folded(2.0, square), _folded(7.0, square)]
    figures = score(recording, np.array([0, 1]), predicted)
    assert figures["hand_deg"] == pytest.approx(4.5, abs=1e-3) and figures["hand_within_4deg"] == 0.5
    assert figures["carried_hand_deg"] == pytest.approx(7.0, abs=1e-3)  # the frame up in the hand


def test_a_shape_any_yaw_fits_has_no_yaw_figure():
    recording = _recording(0.0)
    figures = score(recording, np.array([0, 1]), recording.targets.astype(np.float64))
    assert math.isnan(figures["yaw_deg"]) and figures["right_slot"] == 1.0


def _episodes(kits: list[int]) -> Recording:
    """A recording of one episode per entry of `kits` (that episode's kit), three frames each."""
    recording = _recording(math.pi / 2)
    count = len(kits)
    return dataclasses.replace(
        recording,
        targets=np.repeat(recording.targets[:1], 3 * count, axis=0),
        episode_of=np.repeat(np.arange(count), 3),
        kit=dict(enumerate(kits)),
    )


def test_the_held_out_episodes_are_the_last_tenth_and_hold_out_kits_keeps_their_kits_from_training():
    # 20 episodes on 7 kits: episodes 18 and 19 are held out, their kits 4 and 6 recur in episodes 4, 6, 11, 13
    kits = [i % 7 for i in range(18)] + [4, 6]
    recording = _episodes(kits)
    train, held = split(recording, 100)
    assert set(recording.episode_of[held]) == {18, 19} and set(recording.episode_of[train]) == set(range(18))
    assert len(held) == 6  # every held-out frame when fewer than asked
    train, held = split(recording, 100, hold_out="kits")
    trained = set(recording.episode_of[train].tolist())
    assert trained == set(range(18)) - {4, 6, 11, 13}
    assert not {kits[e] for e in trained} & {4, 6}
    # the first N training episodes only; the held-out frames do not move
    train_n, held_n = split(recording, 100, hold_out="kits", train_episodes=3)
    assert set(recording.episode_of[train_n].tolist()) == {0, 1, 2} and (held_n == held).all()
    assert len(split(recording, 2)[1]) == 2  # at most eval_frames held-out frames


@pytest.mark.parametrize("count", [0, 15])
def test_more_training_episodes_than_there_are_is_one_line(count):
    from kitbench.errors import KitbenchError

    kits = [i % 7 for i in range(18)] + [4, 6]
    with pytest.raises(
        KitbenchError, match=r"--train-episodes .*: .* has 14 training episodes with --hold-out kits; give 1..14"
    ):
        split(_episodes(kits), 100, hold_out="kits", train_episodes=count)


def test_a_recording_whose_every_kit_is_held_out_has_nothing_to_train_on():
    from kitbench.errors import KitbenchError

    with pytest.raises(KitbenchError, match="0 of them to train on with --hold-out kits"):
        split(_episodes([1] * 10), 100, hold_out="kits")


@pytest.fixture(scope="module")
def kits_rgb(tmp_path_factory):
    from kitbench.recording.recorder import load_recipe, record

    out = tmp_path_factory.mktemp("probe") / "kits"
    recipe = load_recipe(ROOT / "datasets" / "assembling_kits_rgb_64.toml", episodes=3, out=out, workers=1)
    record(recipe.replace(mcap=False), progress=False)
    return out


def test_the_probe_trains_each_encoder_and_scores_held_out_episodes(
    kits_rgb, tmp_path, capsys, monkeypatch, needs_vulkan
):
    report = tmp_path / "probe.json"
    argv = [str(kits_rgb), "--encoders", "act,diffusion", "--shifts", "0.05,0", "--steps", "2", "--eval-frames", "8"]
    assert main([*argv, "--out", str(report)]) == 0
    rows = json.loads(report.read_text())["rows"]
    assert [(r["encoder"], r["shift"]) for r in rows] == [
        ("act", 0.05),
        ("act", 0.0),
        ("diffusion", 0.05),
        ("diffusion", 0.0),
    ]
    for row in rows:
        assert row["camera_size"] == "64x64" and row["camera_view"] == "board"
        assert sorted(row["at"], key=int) == ["1", "2"] and row["update_s"] > 0
        for figures in row["at"].values():
            assert 0.0 <= figures["right_slot"] <= 1.0 and math.isfinite(figures["goal_mm"][0])
            # the training frames are scored too: the fit beside what it reads of new episodes
            assert 0.0 <= figures["seen"]["right_slot"] <= 1.0 and math.isfinite(figures["seen"]["goal_mm"][0])
        assert row["hold_out"] == "episodes" and row["train_episodes"] == 2
        # the last of three episodes is held out: its kit's empty pockets give the chance figure
        assert 0.0 < row["baseline"]["chance_right_slot"] <= 1.0
    assert "right slot" in capsys.readouterr().out

    # trained on the turn alone, the probe says only what it trained
    assert main([str(kits_rgb), "--targets", "turn", "--steps", "1", "--eval-frames", "4", "--out", str(report)]) == 0
    printed = capsys.readouterr().out
    assert "turning, " in printed and "over the slot of" in printed
    assert "right slot" not in printed.split("mean predictor")[1].split("\n", 1)[1]
    assert json.loads(report.read_text())["rows"][0]["targets"] == ["turn"]

    # with the arm's state beside the images: the head reads both, and the report says so
    argv = [str(kits_rgb), "--targets", "turn,grip", "--with-state", "--steps", "1", "--eval-frames", "4"]
    assert main([*argv, "--out", str(report)]) == 0
    assert "act+state" in capsys.readouterr().out
    row = json.loads(report.read_text())["rows"][0]
    assert row["with_state"] is True and math.isfinite(row["at"]["1"]["grip_deg"])

    # the state reaches the head: an arm state of NaN makes the loss NaN with --with-state, and only with it
    import studies.assembling_kits_pixels.perception_probe as probe

    recording = probe.read_recording(kits_rgb)
    nan_state = dataclasses.replace(recording, state=np.full_like(recording.state, np.nan))
    monkeypatch.setattr(probe, "read_recording", lambda root: nan_state)
    for flags, finite in (([], True), (["--with-state"], False)):
        assert main([str(kits_rgb), "--targets", "turn", *flags, "--steps", "1", "--out", str(report)]) == 0
        assert math.isfinite(json.loads(report.read_text())["rows"][0]["at"]["1"]["train_l1"]) is finite


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["--encoders", "act,vit"], "unknown encoder 'vit'; valid choices: act, diffusion"),
        (["--targets", "goal,roll"], "unknown target 'roll'; valid choices: goal, yaw, shape, turn, shape_yaw, grip"),
        (["--shifts", "0.9"], "--shifts '0.9': each must be in 0..0.5"),
        (["--shifts", "x"], "--shifts 'x' is not a comma-separated list"),
        (["--steps", "10", "--checkpoints", "20"], "--checkpoints '20': each must be in 1..--steps (10)"),
        (["--hold-out", "shapes"], "--hold-out: unknown choice 'shapes'; valid choices: episodes, kits"),
    ],
)
def test_bad_arguments_are_one_line(argv, needle, tmp_path, capsys):
    assert main([str(tmp_path), *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("perception_probe: error:") and needle in err


def test_a_folder_that_is_not_a_recording_is_one_line(tmp_path, capsys):
    assert main([str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "is not a kitbench recording" in err


def test_the_trained_encoder_starts_a_policy_that_stock_lerobot_train_loads(kits_rgb, tmp_path, needs_vulkan):
    from safetensors.torch import load_file

    from studies.assembling_kits_pixels.perception_probe import (
        open_dataset,
        read_recording,
        split,
        train_and_score,
        write_starting_policy,
    )
    from tests.lerobot_cli import lerobot_train

    config = ROOT / "policies" / "act_assembling_kits_rgb_cpu.json"
    recording = read_recording(kits_rgb)
    train, held = split(recording, 8)
    _, encoder = train_and_score(recording, open_dataset(recording), "act", 0.0, 2, 2, 3e-4, [2], train, held)
    start = tmp_path / "start"
    write_starting_policy(config, recording, encoder, start)
    trained = {f"model.backbone.{k}": v for k, v in encoder.backbone.state_dict().items()}
    saved = load_file(start / "model.safetensors")
    assert trained.keys() <= saved.keys() and all((saved[k] == v).all() for k, v in trained.items())

    # stock lerobot-train starts from it: at learning rate 0 its checkpoint keeps the probe's backbone exactly
    tuned = tmp_path / "tuned"
    frozen = ["--optimizer.lr=0", "--policy.optimizer_lr_backbone=0", "--scheduler.num_warmup_steps=0"]
    args = ["--steps=1", "--save_freq=1", "--batch_size=2", f"--policy.path={start}", *frozen]
    lerobot_train(config, kits_rgb, tuned, tmp_path, *args)
    after = load_file(tuned / "checkpoints" / "last" / "pretrained_model" / "model.safetensors")
    assert all((after[k] == v).all() for k, v in trained.items())


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["--save-policy", "p", "--encoders", "diffusion"], "--save-policy needs one dataset, --encoders act"),
        (["--save-policy", "p", "--shifts", "0,0.05"], "--save-policy needs one dataset, --encoders act"),
        (["--save-policy", "p"], "--save-policy needs --policy-config"),
        (
            ["--save-policy", "p", "--policy-config", str(ROOT / "policies" / "diffusion_lift_peg_upright_rgb.json")],
            "trains 'diffusion'; the probe's encoder is ACT's",
        ),
    ],
)
def test_bad_save_policy_arguments_are_one_line(argv, needle, tmp_path, capsys):
    assert main([str(tmp_path), *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and needle in err
