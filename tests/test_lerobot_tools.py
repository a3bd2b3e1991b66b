"""A kitbench recording stays one through LeRobot's own dataset tools (`lerobot-edit-dataset`: delete_episodes,
split, merge, remove_feature, modify_tasks; `lerobot.datasets.aggregate`): its settings ride in the `episode_seed`
feature's entry and each episode's facts are read back from its columns, so every kitbench command that reads a
recording accepts the result, and a converted or replayed episode keeps its source episode's seed."""

from __future__ import annotations

import importlib.util
import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

from kitbench.cli import main
from kitbench.errors import KitbenchError
from kitbench.metadata import CARRIER, RECORDING_FILE, RecordingInfo, read_episodes
from kitbench.recording.merge import merge
from kitbench.recording.recorder import RecordConfig, record
from kitbench.recording.source import SourceRecording
from tests import launch
from tests.lerobot_cli import OFFLINE

LPU, AK = "LiftPegUpright-v1", "AssemblingKits-v1"


def _edit(repo: str, root: Path, *operation: str, new_root: Path | None = None) -> None:
    """`lerobot-edit-dataset` (its script as `python FILE` runs it), a fork of the test's server (`tests.launch`)."""
    script = importlib.util.find_spec("lerobot.scripts.lerobot_edit_dataset").origin
    cmd = [sys.executable, str(script), "--repo_id", repo, "--root", str(root), *operation]
    if new_root is not None:
        cmd += ["--new_repo_id", f"{repo}_edited", "--new_root", str(new_root)]
    run = launch.run(cmd, text=True, env=OFFLINE, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]


def _facts(root: Path) -> dict[int, tuple]:
    """Each episode's facts by seed: what must survive any tool."""
    return {e.seed: (e.success, e.length, e.first_success, e.task, e.config) for e in read_episodes(root)}


def _actions(root: Path) -> dict[int, np.ndarray]:
    import pandas as pd

    files = sorted((root / "data").rglob("*.parquet"))
    frames = pd.concat([pd.read_parquet(f, columns=["episode_index", "action", CARRIER]) for f in files])
    return {
        int(np.ravel(g[CARRIER].iloc[0])[0]): np.stack(g["action"].to_numpy())
        for _, g in frames.groupby("episode_index")
    }


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    base = tmp_path_factory.mktemp("tools")
    made = {}
    for name, task, seed, episodes, obs_mode in (
        ("lpu", LPU, 0, 4, "state"),
        ("lpu_later", LPU, 100, 2, "state"),
        ("ak_cam", AK, 0, 3, "rgb+depth"),
    ):
        out = base / name
        # the cameras' pixels are not the point: small images (their shapes and the kits are)
        size = {"camera_size": "32x32"} if obs_mode != "state" else {}
        config = RecordConfig.of(task=task, episodes=episodes, out=out, seed=seed, obs_mode=obs_mode, **size)
        record(config, progress=False)
        made[name] = out
    return made


@pytest.fixture(scope="module")
def edited(recordings, tmp_path_factory):
    """`edited(tool, name="lpu")`: the recording `name` after LeRobot's `tool`, made once for the module (the tests
    read the result, never change it)."""
    base = tmp_path_factory.mktemp("edited")
    made: dict[tuple[str, str], Path] = {}

    def get(tool: str, name: str = "lpu") -> Path:
        if (tool, name) not in made:
            made[tool, name] = _edited(recordings, base / name, tool, name)
        return made[tool, name]

    return get


def _edited(recordings, where: Path, tool: str, name: str = "lpu") -> Path:
    """The recording `name` after LeRobot's `tool`, in a new folder under `where`."""
    src = recordings[name]
    out = where / tool
    if tool == "delete_episodes":
        _edit(f"kb/{name}", src, "--operation.type", tool, "--operation.episode_indices", "[1]", new_root=out)
    elif tool == "split":
        _edit(
            f"kb/{name}", src, "--operation.type", tool, "--operation.splits", '{"a": [0, 2], "b": [1]}', new_root=out
        )
        return out / "a"
    elif tool == "remove_feature":
        _edit(
            f"kb/{name}",
            src,
            "--operation.type",
            tool,
            "--operation.feature_names",
            "['commanded_ee_pose']",
            new_root=out,
        )
    elif tool == "modify_tasks":
        shutil.copytree(src, out)
        _edit(f"kb/{name}", out, "--operation.type", tool, "--operation.new_task", "Stand the peg up.")
    elif tool == "merge":
        roots = [str(recordings["lpu_later"]), str(src)]
        _edit(
            "kb/unused", src, "--operation.type", "merge", "--operation.repo_ids", "['kb/a', 'kb/b']",
            "--operation.roots", json.dumps(roots).replace('"', "'"), new_root=out,
        )  # fmt: skip
    elif tool == "aggregate":
        from lerobot.datasets.aggregate import aggregate_datasets

        aggregate_datasets(["kb/a", "kb/b"], "kb/agg", roots=[recordings["lpu_later"], src], aggr_root=out)
    else:
        raise AssertionError(tool)
    return out


TOOLS = ("delete_episodes", "split", "merge", "remove_feature", "modify_tasks", "aggregate")


@pytest.mark.parametrize("tool", TOOLS)
def test_after_each_lerobot_tool_the_recording_reads_with_its_settings_and_episode_facts(recordings, edited, tool):
    out = edited(tool)
    source = RecordingInfo.read(recordings["lpu"])
    info = RecordingInfo.read(out)
    assert info is not None and not info.differences(source, ignore=("seed",)), info
    expected = {
        **_facts(recordings["lpu"]),
        **(_facts(recordings["lpu_later"]) if tool in ("merge", "aggregate") else {}),
    }
    facts = _facts(out)
    if tool == "modify_tasks":  # the new task, everything else as recorded
        assert {f[3] for f in facts.values()} == {"Stand the peg up."}
        expected = {s: (*f[:3], "Stand the peg up.", f[4]) for s, f in expected.items()}
    assert facts == {s: expected[s] for s in facts}
    kept = {"delete_episodes": {0, 2, 3}, "split": {0, 2}}.get(tool, set(expected))
    assert set(facts) == kept
    assert info.seed == min(kept)


@pytest.mark.parametrize("tool", ("delete_episodes", "split", "aggregate", "remove_feature"))
def test_convert_and_replay_read_an_edited_recording_and_keep_each_episode_seed(edited, tmp_path, tool):
    out = edited(tool)
    converted = tmp_path / "converted"
    assert main(["convert", str(out), "--out", str(converted), "--control-mode", "pd_ee_pose"]) == 0
    assert [e.seed for e in read_episodes(converted)] == [e.seed for e in read_episodes(out)]
    assert RecordingInfo.read(converted).source == str(out)
    source = SourceRecording(out)
    actions = _actions(out)
    for seed in source.seeds:  # each seed's frames are that seed's, whatever the renumbering
        np.testing.assert_array_equal(source.episode(seed)["action"], actions[seed])
    replayed = tmp_path / "replayed"
    seed = sorted(source.seeds)[-1]
    assert main(["record", "--task", LPU, "--episodes", "1", "--seed", str(seed), "--policy", f"replay:{out}",
                 "--out", str(replayed), "--no-mcap"]) == 0  # fmt: skip
    np.testing.assert_array_equal(_actions(replayed)[seed], actions[seed])


def test_a_camera_recording_of_assembling_kits_keeps_its_kits_and_shapes_through_delete_and_converts(
    recordings, edited, tmp_path
):
    out = edited("delete_episodes", "ak_cam")
    assert not (out / RECORDING_FILE).exists()  # LeRobot's tool dropped kitbench's files
    facts, source = _facts(out), _facts(recordings["ak_cam"])
    assert facts == {s: source[s] for s in facts} and len(facts) == 2
    assert all({"kit_id", "shape_id", "shape"} <= set(f[4]) for f in facts.values())  # rebuilt from each seed
    converted = tmp_path / "state"
    assert main(["convert", str(out), "--out", str(converted), "--obs-mode", "state"]) == 0
    assert _facts(converted).keys() == facts.keys()
    assert {s: f[4]["shape"] for s, f in _facts(converted).items()} == {s: f[4]["shape"] for s, f in facts.items()}


def test_kitbench_merge_and_lerobots_merge_give_equivalent_recordings(recordings, edited, tmp_path, capsys):
    ours = tmp_path / "ours"
    merge([recordings["lpu_later"], recordings["lpu"]], ours)
    theirs = edited("merge")
    assert not RecordingInfo.read(ours).differences(RecordingInfo.read(theirs))
    assert _facts(ours) == _facts(theirs)
    a, b = _actions(ours), _actions(theirs)
    assert a.keys() == b.keys() and all(np.array_equal(a[s], b[s]) for s in a)
    # and kitbench merges what LeRobot's tools made, saying in one line what they could not carry
    again = tmp_path / "again"
    assert main(["merge", str(edited("delete_episodes")), str(recordings["lpu_later"]),
                 "--out", str(again)]) == 0  # fmt: skip
    lost = [line for line in capsys.readouterr().out.splitlines() if "no MCAP log" in line]
    assert len(lost) == 1 and "3 episode(s)" in lost[0] and "do not copy mcap/" in lost[0]
    assert sorted(_facts(again)) == [0, 2, 3, 100, 101]


def test_a_recording_made_before_settings_rode_in_its_features_still_reads(recordings, tmp_path):
    old = tmp_path / "old"
    shutil.copytree(recordings["lpu"], old)
    info_file = old / "meta/info.json"
    info = json.loads(info_file.read_text())
    info["features"][CARRIER].pop("info")
    info_file.write_text(json.dumps(info, indent=4))
    RecordingInfo.read(old).write(old)  # its settings file, with the digest of its features, as kitbench wrote it then
    assert RecordingInfo.read(old).identity() == RecordingInfo.read(recordings["lpu"]).identity()
    assert _facts(old) == _facts(recordings["lpu"])
    # through a LeRobot tool it is a LeRobot dataset only: one line, nothing written
    edited = tmp_path / "edited"
    _edit("kb/old", old, "--operation.type", "delete_episodes", "--operation.episode_indices", "[0]", new_root=edited)
    with pytest.raises(KitbenchError, match="is not a kitbench recording"):
        SourceRecording(edited)
    out = tmp_path / "converted"
    assert main(["convert", str(edited), "--out", str(out)]) == 2
    assert not out.exists()
    with pytest.raises(KitbenchError, match="recorded before kitbench carried its settings"):
        merge([old, recordings["lpu_later"]], tmp_path / "mixed")
