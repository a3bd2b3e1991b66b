"""`kitbench convert`: a recording re-simulated from its seeds and executed actions into other observations or
another action space, each episode checked against its source, with the recorder's durability and bad-input rules."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from kitbench.recording.convert import convert_config
from kitbench.recording.recorder import RecordConfig, record
from tests import launch
from tests.processes import kill_once_committed
from tests.test_recording import _columns, _load, kits_successes_only

TASK = "LiftPegUpright-v1"
COLUMNS = ("observation.state", "observation.environment_state", "action", "executed_action", "episode_seed")


def _source(root: Path, control_mode: str, episodes: int = 3, **kwargs) -> Path:
    """An expert recording with noise (so `executed_action` differs from `action`) and settling."""
    config = RecordConfig.of(
        TASK, episodes, root, control_mode=control_mode, action_noise=0.05, settle_steps=2, **kwargs
    )
    record(config, progress=False)
    return root


@pytest.fixture(scope="module")
def joint_delta_source(tmp_path_factory):
    return _source(tmp_path_factory.mktemp("convert") / "src", "pd_joint_target_delta_pos", mcap=False)


def test_cameras_rendered_afterwards_are_the_frames_of_a_direct_recording(joint_delta_source, tmp_path, needs_vulkan):
    converted = tmp_path / "converted"
    summary = record(convert_config(joint_delta_source, converted, obs_mode="rgb+depth+segmentation"), progress=False)
    assert summary.stored == 3 and summary.rejected == 0
    direct = _source(tmp_path / "direct", "pd_joint_target_delta_pos", obs_mode="rgb+depth+segmentation")
    a, b, src = _columns(converted), _columns(direct), _columns(joint_delta_source)
    for name in COLUMNS:
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)
        np.testing.assert_array_equal(a[name], src[name], err_msg=name)
    converted_ds, direct_ds = _load(converted), _load(direct)
    for i in (0, len(direct_ds) // 2, len(direct_ds) - 1):
        for name in converted_ds.meta.camera_keys:
            np.testing.assert_array_equal(converted_ds[i][name].numpy(), direct_ds[i][name].numpy(), err_msg=name)
    assert len(list((converted / "mcap").glob("*.mcap"))) == 3  # MCAP logs converted too
    settings = json.loads((converted / "meta/kitbench_recording.json").read_text())
    assert settings["source"] == str(joint_delta_source) and settings["obs_mode"] == "rgb+depth+segmentation"
    assert (
        f"kitbench convert {joint_delta_source} --obs-mode rgb+depth+segmentation"
        in (converted / "README.md").read_text()
    )


@pytest.mark.parametrize("mode", ["pd_joint_pos", "pd_ee_pose", "pd_ee_target_delta_pose"])
def test_another_action_space_tracks_the_joint_trajectory(joint_delta_source, tmp_path, mode):
    """From joint target deltas every target fits these modes' action boxes: every episode reproduces its source,
    exactly in absolute joint targets, within the tolerance in end-effector poses and target deltas. (A measured
    delta mode cannot reach targets that lead the joints by up to 0.4 rad in one step under ManiSkill's drives.)"""
    import gymnasium as gym

    out = tmp_path / mode
    summary = record(convert_config(joint_delta_source, out, control_mode=mode), progress=False)
    assert summary.stored == 3 and summary.rejected == 0
    a, src = _columns(out), _columns(joint_delta_source)
    source_episodes = [json.loads(x) for x in (joint_delta_source / "meta/kitbench_episodes.jsonl").open()]
    episodes = [json.loads(x) for x in (out / "meta/kitbench_episodes.jsonl").open()]
    assert [e["success"] for e in episodes] == [e["success"] for e in source_episodes]
    if mode == "pd_joint_pos":  # the very joint targets: the very states
        np.testing.assert_array_equal(a["observation.state"], src["observation.state"])
    elif mode == "pd_joint_target_delta_pos":  # the same targets through float32 differences of them
        np.testing.assert_allclose(a["observation.state"], src["observation.state"], atol=1e-5)
    # the stored actions mean what they say: replayed in the new mode from the seed, they end as the source did
    for episode in episodes:
        env = gym.make(f"kitbench/{TASK}", control_mode=mode)
        env.reset(seed=episode["seed"])
        for action in a["executed_action"][a["episode_index"].reshape(-1) == episode["episode_index"]]:
            _, _, _, _, info = env.step(action)
        assert bool(info["success"]) == episode["success"]
        env.close()


def test_absolute_targets_beyond_a_delta_box_are_reached_with_catch_up_steps(tmp_path):
    """The expert's absolute joint targets lead the joints by up to 0.2 rad, past the 0.1 rad a joint-delta step
    may command: the converted arm gets extra steps to reach each target, so its episodes run longer than their
    sources, yet the peg follows its source path and stands up as it did; and the stored actions, replayed in the
    new mode from the seed, do the same."""
    import gymnasium as gym

    from kitbench.recording.convert import CATCH_UP_STEPS

    assert CATCH_UP_STEPS >= 1
    source = _source(tmp_path / "src", "pd_joint_pos", episodes=3, mcap=False)
    out = tmp_path / "deltas"
    summary = record(convert_config(source, out, control_mode="pd_joint_target_delta_pos", mcap=False), progress=False)
    assert summary.stored + summary.rejected == 3 and summary.stored >= 2
    a, src = _columns(out), _columns(source)
    source_lengths = {e["seed"]: e["length"] for e in map(json.loads, (source / "meta/kitbench_episodes.jsonl").open())}
    for episode in map(json.loads, (out / "meta/kitbench_episodes.jsonl").open()):
        assert episode["length"] > source_lengths[episode["seed"]]  # catch-up steps were taken
        env = gym.make(f"kitbench/{TASK}", control_mode="pd_joint_target_delta_pos")
        env.reset(seed=episode["seed"])
        actions = a["executed_action"][a["episode_index"].reshape(-1) == episode["episode_index"]]
        assert np.abs(actions[:, :-1]).max() <= 1.0 + 1e-6  # every arm step within the delta box (ManiSkill's [-1, 1])
        for action in actions:
            _, _, _, _, info = env.step(action)
        assert bool(info["success"]) and episode["success"]
        env.close()
    assert len(src["action"]) < len(a["action"])


def swap_seeds(root: Path) -> None:
    """Swap the first two episodes' seeds everywhere a recording keeps them (its data's `episode_seed` column, its
    episode file, the digest written with it), as a recorder that mixed them up would have written them."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from kitbench.metadata import RecordingInfo

    data = next((root / "data").rglob("*.parquet"))
    table = pq.read_table(data)
    episode, seed = table.column("episode_index").to_numpy(), table.column("episode_seed").to_numpy().copy()
    first, second = seed[episode == 0][0], seed[episode == 1][0]
    seed[episode == 0], seed[episode == 1] = second, first
    column = table.schema.get_field_index("episode_seed")
    pq.write_table(table.set_column(column, table.schema.field(column), pa.array(seed)), data)
    episodes_file = root / "meta/kitbench_episodes.jsonl"
    episodes = [json.loads(x) for x in episodes_file.open()]
    episodes[0]["seed"], episodes[1]["seed"] = episodes[1]["seed"], episodes[0]["seed"]
    episodes_file.write_text("".join(json.dumps(e) + "\n" for e in episodes))
    info = RecordingInfo.read(root)
    info.seeds = [e["seed"] for e in episodes]  # no longer consecutive: the settings list them
    info.write(root)


def test_an_episode_that_diverges_is_reported_and_not_stored(tmp_path):
    """A source whose seeds no longer match its actions (two episodes' seeds swapped): each replay grasps where
    the other episode's peg lay, and the conversion says so instead of storing it."""
    source = _source(tmp_path / "src", "pd_joint_pos", episodes=2, mcap=False)
    swap_seeds(source)
    out = tmp_path / "deltas"
    run = launch.run(
        [sys.executable, "-m", "kitbench.cli", "convert", str(source), "--out", str(out)]
        + ["--control-mode", "pd_joint_target_delta_pos"],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert run.returncode == 0, run.stderr[-2000:]
    assert "seed 0: not stored, " in run.stderr and "seed 1: not stored, " in run.stderr
    assert "not stored because they diverged from the source: 2 episode(s)" in run.stdout
    assert not (out / "meta/kitbench_episodes.jsonl").exists()


def freeze_episode(root: Path, index: int) -> None:
    """Make episode `index`'s executed actions all its first one (the arm holds still where its expert moved), as
    a source whose actions were damaged would hold them: its replay leaves the peg where it lay."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    data = next((root / "data").rglob("*.parquet"))
    table = pq.read_table(data)
    episode = table.column("episode_index").to_numpy()
    executed = np.stack(table.column("executed_action").to_numpy(zero_copy_only=False))
    executed[episode == index] = executed[episode == index][0]
    column = table.schema.get_field_index("executed_action")
    field = table.schema.field(column)
    pq.write_table(table.set_column(column, field, pa.array(list(executed), type=field.type)), data)


def test_a_diverged_episode_between_stored_ones_leaves_a_dataset_that_passes_the_training_checks(tmp_path):
    """A source of consecutive seeds whose middle episode diverges: the conversion stores seeds 0 and 2, lists
    them in its settings, and the checks lerobot-train runs through the plugin accept it (they refused it, seeds
    0..1 said against 0, 2 held)."""
    from kitbench.integrity import check_dataset
    from kitbench.metadata import RecordingInfo
    from kitbench.recording.source import SourceRecording

    source = _source(tmp_path / "src", "pd_joint_pos", episodes=3, mcap=False)
    freeze_episode(source, 1)
    assert RecordingInfo.read(source).seeds is None  # consecutive: the settings imply them
    out = tmp_path / "deltas"
    summary = record(convert_config(source, out, control_mode="pd_joint_target_delta_pos", mcap=False), progress=False)
    assert summary.stored == 2 and summary.rejected == 1
    check_dataset(out)
    assert SourceRecording(out).seeds == (0, 2) and RecordingInfo.read(out).seeds == [0, 2]


def test_a_recording_of_successes_only_converts_into_a_dataset_that_passes_the_training_checks(tmp_path):
    """An `only_success` source skips the seeds its expert failed (seed 3: `kits_successes_only`'s expert);
    the conversion holds the same seeds, gap included, and says it holds successes only, so that the checks
    lerobot-train runs through the plugin accept it (they refused it, seeds 0..3 asked against 0..4 held)."""
    from kitbench.integrity import check_dataset
    from kitbench.metadata import RecordingInfo
    from kitbench.recording.source import SourceRecording

    source = tmp_path / "src"
    record(kits_successes_only(source, 4), progress=False)
    assert SourceRecording(source).seeds == (0, 1, 2, 4)
    out = tmp_path / "converted"
    summary = record(convert_config(source, out, mcap=False), progress=False)
    assert summary.stored == 4 and summary.rejected == 0
    check_dataset(out)
    assert SourceRecording(out).seeds == (0, 1, 2, 4) and RecordingInfo.read(out).only_success


def test_path_gap_ignores_timing_and_measures_a_detour():
    from kitbench.recording.convert import path_gap

    rng = np.random.default_rng(0)
    path = np.cumsum(rng.uniform(0, 0.01, size=(40, 6)), axis=0)  # two objects' positions along an episode
    assert path_gap(path, path) == 0.0
    slowed = np.repeat(path, 3, axis=0)  # the same path at a third of the speed
    assert path_gap(slowed, path) == 0.0
    between = np.empty((79, 6))  # frames on the source's frames and halfway between them
    between[0::2], between[1::2] = path, (path[:-1] + path[1:]) / 2
    assert path_gap(between, path) < 1e-12
    detour = path.copy()
    detour[20, 3:] += [0.0, 0.0, 0.02]  # the second object lifted 2 cm off its path at one frame
    assert path_gap(detour, path) == pytest.approx(0.02, abs=0.003)
    assert path_gap(path[:20], path) > 0.05  # stopped halfway: the rest of the path was never followed


def test_kill_minus_nine_loses_at_most_the_episode_in_flight_and_resume_finishes_identically(tmp_path):
    source = _source(tmp_path / "src", "pd_joint_target_delta_pos", episodes=6, mcap=False)
    out, reference = tmp_path / "killed", tmp_path / "reference"
    cmd = [sys.executable, "-m", "kitbench.cli", "convert", str(source), "--control-mode", "pd_joint_pos"]
    cmd += ["--no-mcap", "--commit-interval", "0"]
    kill_once_committed([*cmd, "--out", str(out)], out)
    kept = _load(out).num_episodes
    assert 2 <= kept < 6
    launch.run([*cmd, "--out", str(out), "--resume"], check=True, capture_output=True, timeout=600)
    launch.run([*cmd, "--out", str(reference)], check=True, capture_output=True, timeout=600)
    a, b = _columns(out), _columns(reference)
    for name in (*COLUMNS, "episode_index", "frame_index"):
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)


@pytest.mark.parametrize(
    ("make_args", "needle"),
    [
        (lambda src, tmp: [str(tmp / "nothing"), "--out", str(tmp / "dst")], "is not a kitbench recording"),
        (
            lambda src, tmp: [str(src), "--obs-mode", "pointclouds", "--out", str(tmp / "dst")],
            "unknown obs_mode 'pointclouds'; valid choices: state, rgb, rgbd",
        ),
        (
            lambda src, tmp: [str(src), "--control-mode", "pd_joint_vel", "--out", str(tmp / "dst")],
            "unknown control_mode 'pd_joint_vel'; valid choices",
        ),
        (lambda src, tmp: [str(src), "--out", str(src)], "exists; pass --resume to continue it or --overwrite"),
    ],
)
def test_bad_input_is_one_line_and_writes_nothing(joint_delta_source, tmp_path, make_args, needle):
    before = sorted(p.name for p in joint_delta_source.rglob("*"))
    run = launch.run(
        [sys.executable, "-m", "kitbench.cli", "convert", *make_args(joint_delta_source, tmp_path)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert run.returncode == 2 and run.stderr.count("\n") == 1 and needle in run.stderr, run.stderr
    assert not (tmp_path / "dst").exists()
    assert sorted(p.name for p in joint_delta_source.rglob("*")) == before


def _as_recorded_before_the_convention(source: Path, old: Path) -> Path:
    """A copy of `source` as kitbench wrote it before it took ManiSkill's convention: no `action_convention`, the
    joint deltas in radians and the gripper's sign the other way round in every action column (the simulation's
    outcome is the same)."""
    import shutil

    import pyarrow as pa
    import pyarrow.parquet as pq

    from kitbench.metadata import CARRIER, INFO_FILE, RECORDING_FILE, RecordingInfo

    shutil.copytree(source, old)
    for path in (old / "data").rglob("*.parquet"):
        table = pq.read_table(path)
        for name in ("action", "executed_action"):
            rows = np.stack(table.column(name).to_numpy(zero_copy_only=False)).copy()
            rows[:, :7] *= 0.1  # pd_joint_target_delta_pos on the Panda: 7 joint deltas in radians, then the gripper
            rows[:, 7] = -rows[:, 7]
            column = table.schema.get_field_index(name)
            field = table.schema.field(name)
            table = table.set_column(column, field, pa.array(rows.tolist(), type=field.type))
        pq.write_table(table, path)
    info_file = old / INFO_FILE
    lerobot = json.loads(info_file.read_text())
    del lerobot["features"][CARRIER]["info"]["kitbench"]["action_convention"]
    info_file.write_text(json.dumps(lerobot, indent=4))
    settings = json.loads((old / RECORDING_FILE).read_text())
    del settings["action_convention"]
    RecordingInfo.from_json(settings).write(old)
    return old


def test_a_recording_made_before_the_convention_is_refused_or_migrated(joint_delta_source, tmp_path):
    """Eval's replay, merge and a trained policy's dataset refuse it in one line naming `kitbench convert`, and
    `kitbench convert` migrates it: the same episodes, its gripper commands turned to ManiSkill's sign."""
    from kitbench.errors import KitbenchError
    from kitbench.policies.replay import ReplayPolicy
    from kitbench.recording.merge import merge

    old = _as_recorded_before_the_convention(joint_delta_source, tmp_path / "old")
    with pytest.raises(KitbenchError, match=r"gripper \+1 closed.*kitbench convert") as caught:
        ReplayPolicy(str(old))
    assert "\n" not in str(caught.value)
    with pytest.raises(KitbenchError, match="kitbench convert"):
        merge([old, joint_delta_source], tmp_path / "merged")
    assert not (tmp_path / "merged").exists()
    migrated = tmp_path / "migrated"
    summary = record(convert_config(old, migrated), progress=False)
    assert summary.stored == 3 and summary.rejected == 0
    a, src = _columns(migrated), _columns(joint_delta_source)
    for name in COLUMNS:  # radians to ManiSkill's units and back in float32: within its rounding
        np.testing.assert_allclose(a[name], src[name], atol=1e-5, err_msg=name)
    assert json.loads((migrated / "meta/kitbench_recording.json").read_text())["action_convention"] == "maniskill-3.0.1"
