"""A dataset folder damaged by hand (a file truncated, deleted or edited) is refused in one line that names the
file, by every command that reads one, with nothing written; and a few hundred seeded mutations of the metadata
files (LeRobot's info.json and episode index, kitbench's settings and episode file) each end in such a line or
in the answer the undamaged folder gives: never a traceback, never a wrong answer read without a word."""

from __future__ import annotations

import json
import os
import random
import shutil
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

import kitbench  # noqa: F401
from kitbench.errors import KitbenchError
from kitbench.integrity import Damage, check_dataset
from kitbench.metadata import EPISODES_FILE, INFO_FILE, RECORDING_FILE, RecordingInfo, lerobot_info, read_episodes
from kitbench.recording.journal import journal_root
from kitbench.recording.recorder import RecordConfig, record
from tests import launch

ROOT = Path(__file__).resolve().parents[1]
TASK = "LiftPegUpright-v1"
EPISODES = 4
ENV = {**os.environ, "HF_HUB_OFFLINE": "1"}


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("recording") / "ds"
    record(RecordConfig.of(task=TASK, episodes=EPISODES, out=out), progress=False)
    return out


def _episode_index(root: Path) -> Path:
    return next((root / "meta/episodes").rglob("*.parquet"))


def _data_file(root: Path) -> Path:
    return next((root / "data").rglob("*.parquet"))


# -- what the readers answer -------------------------------------------------------------------------------
def answer(root: Path) -> dict:
    """What kitbench's readers and the training reader read of the dataset at `root`: its settings, each
    episode's facts, LeRobot's counts, features, tasks and a sample from each end."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from kitbench.training.reader import install

    install()
    check_dataset(root)
    settings = RecordingInfo.read(root)
    assert settings is not None
    dataset = LeRobotDataset("kitbench/test", root=root)
    info = lerobot_info(root)
    samples = [dataset[0], dataset[len(dataset) - 1]]
    return {
        # what a recording is (its identity), not how it is described (repo id, the command that made it)
        "settings": {**settings.identity(), "fps": settings.fps, "seeds": settings.seeds},
        "episodes": [e.to_json() for e in read_episodes(root)],
        "info": {k: info[k] for k in ("fps", "features", "total_episodes", "total_frames", "codebase_version")},
        "tasks": list(dataset.meta.tasks.index),
        "samples": [{k: (v.tolist() if hasattr(v, "tolist") else v) for k, v in s.items()} for s in samples],
    }


# -- mutations ---------------------------------------------------------------------------------------------
def _json_paths(value, path=()):
    """Every (path to a value) inside a JSON document."""
    yield path
    if isinstance(value, dict):
        for k, v in value.items():
            yield from _json_paths(v, (*path, k))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            yield from _json_paths(v, (*path, i))


def _changed(value, rng: random.Random):
    """A plausible hand edit of a JSON value."""
    if isinstance(value, bool):
        return rng.choice([not value, None, int(value), str(value).lower()])
    if isinstance(value, int):
        return rng.choice([value + 1, value - 1, -value - 1, value * 2 + 1, str(value), None, float(value) + 0.5])
    if isinstance(value, float):
        return rng.choice([value * 2 + 1, -value - 1, str(value), None, int(value) + 1])
    if isinstance(value, str):
        return rng.choice(["", value + "x", value[:-1], 0, None])
    if isinstance(value, list):
        return rng.choice([value[:-1], [*value, value[-1] if value else 0], list(reversed(value)), {}, None])
    if isinstance(value, dict):
        return rng.choice([{}, [], None, {**value, "unknown_key": 1}])
    return rng.choice([0, "", []])


def _edit_json(document, rng: random.Random):
    paths = list(_json_paths(document))[1:] or [()]
    path = rng.choice(paths)
    if not path:
        return _changed(document, rng)
    parent = document
    for key in path[:-1]:
        parent = parent[key]
    if rng.random() < 0.25 and isinstance(parent, dict):
        del parent[path[-1]]
    else:
        parent[path[-1]] = _changed(parent[path[-1]], rng)
    return document


def _bytes_edit(path: Path, rng: random.Random) -> str:
    data = path.read_bytes()
    kind = rng.choice(["truncate", "flip", "insert", "empty", "delete"])
    if kind == "truncate":
        path.write_bytes(data[: rng.randrange(len(data))])
    elif kind == "flip":
        at = rng.randrange(len(data))
        path.write_bytes(data[:at] + bytes([data[at] ^ (1 << rng.randrange(8))]) + data[at + 1 :])
    elif kind == "insert":
        at = rng.randrange(len(data))
        path.write_bytes(data[:at] + bytes(rng.randrange(256) for _ in range(rng.randint(1, 8))) + data[at:])
    elif kind == "empty":
        path.write_bytes(b"")
    else:
        path.unlink()
    return kind


def _jsonl_edit(path: Path, rng: random.Random) -> str:
    lines = path.read_text().splitlines()
    kind = rng.choice(["drop", "duplicate", "swap", "value"])
    i, j = rng.randrange(len(lines)), rng.randrange(len(lines))
    if kind == "drop":
        del lines[i]
    elif kind == "duplicate":
        lines.insert(j, lines[i])
    elif kind == "swap":
        lines[i], lines[j] = lines[j], lines[i]
    else:
        lines[i] = json.dumps(_edit_json(json.loads(lines[i]), rng))
    path.write_text("".join(line + "\n" for line in lines))
    return kind


def _parquet_edit(path: Path, rng: random.Random) -> str:
    table = pq.read_table(path)
    kind = rng.choice(["value", "value", "drop row", "duplicate row", "drop column"])
    rows = table.to_pylist()
    if kind == "drop column":
        table = table.drop_columns([rng.choice(table.column_names)])
        pq.write_table(table, path)
        return kind
    if kind == "drop row":
        del rows[rng.randrange(len(rows))]
    elif kind == "duplicate row":
        rows.insert(rng.randrange(len(rows)), rows[rng.randrange(len(rows))])
    else:
        row, name = rows[rng.randrange(len(rows))], rng.choice(table.column_names)
        value = row[name]
        if isinstance(value, bool):
            row[name] = not value
        elif isinstance(value, int | float):
            row[name] = value + rng.choice([1, -1, 2])
        elif isinstance(value, list) and value:
            row[name] = [*value[:-1], value[-1] + 1 if isinstance(value[-1], int | float) else "x"]
        kind = f"value {name}"
    pq.write_table(pa.Table.from_pylist(rows, schema=table.schema), path)
    return kind


def mutate(root: Path, seed: int) -> str:
    """One seeded hand edit of a metadata file of the dataset at `root`; returns what was done."""
    rng = random.Random(seed)
    target = rng.choice([INFO_FILE, "episode index", RECORDING_FILE, EPISODES_FILE])
    path = _episode_index(root) if target == "episode index" else root / target
    if rng.random() < 0.3:
        return f"{target}: {_bytes_edit(path, rng)}"
    if target == "episode index":
        return f"{target}: {_parquet_edit(path, rng)}"
    if target == EPISODES_FILE:
        return f"{target}: {_jsonl_edit(path, rng)}"
    path.write_text(json.dumps(_edit_json(json.loads(path.read_text()), rng), indent=2))
    return f"{target}: edited"


MUTATIONS = int(os.environ.get("KITBENCH_MUTATIONS", "300"))


def test_hundreds_of_metadata_mutations_are_refused_in_one_line_or_read_as_before(recording, tmp_path):
    before = answer(recording)
    refused, same = 0, 0
    for seed in range(MUTATIONS):
        copy = tmp_path / f"m{seed}"
        shutil.copytree(recording, copy)
        what = mutate(copy, seed)
        try:
            after = answer(copy)
        except KitbenchError as exc:
            message = str(exc)
            assert "\n" not in message and str(copy) in message, (seed, what, message)
            refused += 1
        except Exception as exc:  # noqa: BLE001  (anything else is the traceback this test forbids)
            pytest.fail(f"mutation {seed} ({what}): {type(exc).__name__}: {exc}")
        else:
            assert after == before, f"mutation {seed} ({what}) was read without a word, and differently"
            same += 1
        shutil.rmtree(copy)
    assert refused + same == MUTATIONS and refused > MUTATIONS // 2  # most edits matter


# -- every command, on a damaged folder -----------------------------------------------------------------------
DAMAGE = {
    "a truncated data file": lambda root: _truncate(_data_file(root)),
    "a deleted info.json": lambda root: (root / INFO_FILE).unlink(),
    "an edited episode file": lambda root: (root / EPISODES_FILE).write_text(
        (root / EPISODES_FILE).read_text().replace('"success": true', '"success": false', 1)
    ),
    "a truncated episode index": lambda root: _truncate(_episode_index(root)),
}


def _truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def _commands(damaged: Path, other: Path, out: Path) -> dict[str, list[str]]:
    kb = [sys.executable, "-m", "kitbench.cli"]
    return {
        "record --resume": [
            *kb,
            "record",
            "--task",
            TASK,
            "--episodes",
            str(EPISODES + 1),
            "--out",
            str(damaged),
            "--resume",
        ],
        "convert": [*kb, "convert", str(damaged), "--out", str(out), "--control-mode", "pd_joint_pos"],
        "eval --policy replay:": [
            *kb,
            "eval",
            "--task",
            TASK,
            "--seed",
            "0",
            "--episodes",
            "2",
            "--policy",
            f"replay:{damaged}",
            "--out",
            str(out),
        ],
        "view": [*kb, "view", str(damaged), "--episode", "0", "--save", str(out)],
        "merge": [*kb, "merge", str(other), str(damaged), "--out", str(out)],
    }


@pytest.fixture(scope="module")
def other(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("other") / "ds"
    record(RecordConfig.of(task=TASK, episodes=2, seed=EPISODES, out=out), progress=False)
    return out


@pytest.mark.parametrize("damage", DAMAGE, ids=DAMAGE)
def test_every_command_refuses_a_damaged_dataset_in_one_line_naming_the_file(recording, other, tmp_path, damage):
    damaged = tmp_path / "ds"
    shutil.copytree(recording, damaged)
    DAMAGE[damage](damaged)
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    for name, cmd in _commands(damaged, other, tmp_path / "out").items():
        run = launch.run(cmd, env=ENV, cwd=ROOT, capture_output=True, text=True, timeout=300)
        lines = run.stderr.strip().splitlines()
        assert run.returncode != 0, (name, run.stdout[-1000:])
        assert len(lines) == 1 and str(damaged) in lines[0], (name, run.stderr[-3000:])
        assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before, name  # nothing written
    assert not journal_root(damaged).exists()


def test_lerobot_train_refuses_a_damaged_recording_in_one_line(recording, tmp_path):
    """The training reader, as lerobot-train meets it through kitbench's plugin."""
    damaged = tmp_path / "ds"
    shutil.copytree(recording, damaged)
    _truncate(_data_file(damaged))
    config = json.loads((ROOT / "policies/act_lift_peg_upright_state.json").read_text())
    config["dataset"]["root"] = str(damaged)
    (tmp_path / "config.json").write_text(json.dumps(config))
    run = launch.run(
        [
            str(Path(sys.executable).parent / "lerobot-train"),
            f"--config_path={tmp_path / 'config.json'}",
            f"--output_dir={tmp_path / 'train'}",
            "--steps=2",
            "--policy.device=cpu",
            "--num_workers=0",
        ],
        env=ENV,
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert run.returncode != 0
    errors = [line for line in run.stderr.splitlines() if "error" in line.lower()]
    assert len(errors) == 1 and "Traceback" not in run.stderr, run.stderr[-3000:]
    assert errors[0].startswith(f"lerobot-train: error: {_data_file(damaged)}: unreadable")
    assert not (tmp_path / "train" / "checkpoints").exists()


def test_a_damaged_journal_entry_is_recorded_again_in_seed_order(recording, tmp_path):
    """A journal entry damaged on disk (a kill never leaves one) is recorded again, with those after it, and the
    recording equals the undamaged one."""
    from tests.datasets_equal import no_leftovers, same_content
    from tests.processes import record_command
    from tests.test_kill_points import killed_at

    out = tmp_path / "ds"
    cmd = record_command(out, TASK, "--episodes", str(EPISODES))
    killed_at(cmd, f"writer.saved:{EPISODES - 1}")
    entries = sorted(journal_root(out).glob("seed-*.npz"))
    assert len(entries) == EPISODES - 1
    _truncate(entries[1])
    run = launch.run([*cmd, "--resume"], env=ENV, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    assert f"{entries[1]} is unreadable" in run.stderr and f"seeds 1-{EPISODES - 2} recorded again" in run.stderr
    same_content(recording, out)
    no_leftovers(out)


def test_the_check_reads_an_undamaged_recording_and_a_damaged_one_names_the_file(recording):
    check_dataset(recording)
    with pytest.raises(KitbenchError, match="does not exist"):
        check_dataset(recording.parent / "nowhere")
    assert issubclass(Damage, KitbenchError)
    np.testing.assert_array_equal([e.seed for e in read_episodes(recording)], range(EPISODES))


@pytest.mark.parametrize("cut", [0.5, 0.97])
def test_a_truncated_video_file_is_named(needs_vulkan, tmp_path_factory, tmp_path, cut):
    """A camera recording's video, cut short (a copy that stopped part-way): its moov atom is at the front, so
    the file still opens; decoding its last episode's last frame is what finds it."""
    out = tmp_path_factory.getbasetemp() / "video" / "ds"
    if not out.exists():
        record(RecordConfig.of(task=TASK, episodes=2, out=out, obs_mode="rgb"), progress=False)
    copy = tmp_path / "ds"
    shutil.copytree(out, copy)
    check_dataset(copy)
    video = next((copy / "videos").rglob("*.mp4"))
    video.write_bytes(video.read_bytes()[: int(video.stat().st_size * cut)])
    with pytest.raises(Damage) as caught:
        check_dataset(copy)
    assert caught.value.path == video
