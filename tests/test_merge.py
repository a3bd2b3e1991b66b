"""`kitbench merge`: recordings of disjoint seed ranges merge, through LeRobot's aggregation, into the dataset one
recording of all the seeds makes (frames, indices, episode metadata, MCAP logs, decoded video frames); bad shards
are refused before anything is written."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from kitbench.cli import main
from kitbench.errors import KitbenchError
from kitbench.recording.merge import merge
from kitbench.recording.recorder import RecordConfig, record

os.environ.setdefault("HF_HUB_OFFLINE", "1")
TASK = "LiftPegUpright-v1"


def _record(out: Path, seed: int, episodes: int, **settings) -> Path:
    record(RecordConfig.of(task=TASK, episodes=episodes, out=out, seed=seed, **settings), progress=False)
    return out


def _frames(root: Path):
    import pandas as pd

    return pd.concat([pd.read_parquet(p) for p in sorted((root / "data").rglob("*.parquet"))], ignore_index=True)


def _assert_same_recording(a: Path, b: Path) -> None:
    fa, fb = _frames(a), _frames(b)
    assert list(fa.columns) == list(fb.columns) and len(fa) == len(fb)
    for column in fa.columns:  # episode_index and index included: renumbered as one recording numbers them
        np.testing.assert_array_equal(np.stack(fa[column].to_numpy()), np.stack(fb[column].to_numpy()), column)
    assert (a / "meta/kitbench_episodes.jsonl").read_bytes() == (b / "meta/kitbench_episodes.jsonl").read_bytes()
    assert json.loads((a / "meta/kitbench_recording.json").read_text()) == json.loads(
        (b / "meta/kitbench_recording.json").read_text()
    )
    logs = sorted(p.name for p in (a / "mcap").iterdir())
    assert logs == sorted(p.name for p in (b / "mcap").iterdir())
    for name in logs:
        assert (a / "mcap" / name).read_bytes() == (b / "mcap" / name).read_bytes(), name


@pytest.fixture(scope="module")
def state_shards(tmp_path_factory):
    root = tmp_path_factory.mktemp("shards")
    whole = _record(root / "whole", 0, 4)
    return whole, [_record(root / "s0", 0, 2), _record(root / "s1", 2, 1), _record(root / "s2", 3, 1)]


def test_merged_shards_are_the_recording_of_all_their_seeds(state_shards, tmp_path):
    whole, shards = state_shards
    out = tmp_path / "merged"
    assert main(["merge", str(shards[2]), str(shards[0]), str(shards[1]), "--out", str(out)]) == 0  # any order
    _assert_same_recording(whole, out)
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    ds = LeRobotDataset("kitbench/merged", root=out)
    assert ds.num_episodes == 4 and len(ds) == ds.meta.total_frames == len(_frames(whole))
    assert [int(s) for s in ds.hf_dataset["episode_seed"][:: len(ds) - 1]] == [0, 3]


def test_merged_camera_video_decodes_to_the_same_frames(needs_vulkan, tmp_path):
    whole = _record(tmp_path / "whole", 0, 2, obs_mode="rgb", mcap=False)
    a = _record(tmp_path / "a", 0, 1, obs_mode="rgb", mcap=False)
    b = _record(tmp_path / "b", 1, 1, obs_mode="rgb", mcap=False)
    out = tmp_path / "merged"
    merge([b, a], out)
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    one, merged = LeRobotDataset("kitbench/w", root=whole), LeRobotDataset("kitbench/m", root=out)
    assert len(one) == len(merged)
    key = next(k for k in one.meta.video_keys)
    for i in range(len(one)):
        assert np.array_equal(one[i][key].numpy(), merged[i][key].numpy()), i


def test_overlapping_seeds_are_refused_and_nothing_is_written(state_shards, tmp_path):
    whole, shards = state_shards
    out = tmp_path / "merged"
    with pytest.raises(KitbenchError, match=r"^seed 0 is in both .* shards must not overlap$"):
        merge([whole, shards[0]], out)
    assert list(tmp_path.iterdir()) == []


def test_shards_with_other_settings_are_refused(state_shards, tmp_path):
    _, shards = state_shards
    other = _record(tmp_path / "other", 10, 1, control_mode="pd_ee_delta_pose")
    with pytest.raises(KitbenchError) as err:
        merge([shards[0], other], tmp_path / "merged")
    assert "were recorded with different control_mode ('pd_joint_pos' and 'pd_ee_delta_pose')" in str(err.value)
    assert not (tmp_path / "merged").exists()


def test_bad_merges_are_one_line_errors(state_shards, tmp_path, capsys):
    _, shards = state_shards
    unfinished = tmp_path / "unfinished"
    unfinished.mkdir()
    (tmp_path / "unfinished.journal").mkdir()
    taken = tmp_path / "taken"
    taken.mkdir()
    cases = [
        ([str(shards[0])], "merge needs at least two recordings, got 1"),
        ([str(shards[0]), str(tmp_path / "nowhere")], f"shard {tmp_path / 'nowhere'} does not exist"),
        ([str(shards[0]), str(unfinished)], f"shard {unfinished} is an unfinished recording"),
        ([str(shards[0]), str(shards[1]), "--out", str(taken)], f"output folder {taken} exists"),
    ]
    for argv, message in cases:
        if "--out" not in argv:
            argv = [*argv, "--out", str(tmp_path / "merged")]
        assert main(["merge", *argv]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"kitbench merge: error: {message}"), err
    assert not (tmp_path / "merged").exists() and list(taken.iterdir()) == []
