"""The other writers killed at their named fault points (`kitbench.faults`): a sharded recording, a conversion, an
evaluation saving its dataset and a merge each resume (or run again) into what an uninterrupted run makes, nothing
left beside it. The recording's own fault points are in test_kill_points.py, whose reference recording and kill
helper these share (a file of their own so that the two halves run on two test workers)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from kitbench.metadata import read_episodes
from kitbench.recording.dataset import recover
from kitbench.recording.recorder import RecordConfig, record
from tests import launch
from tests.datasets_equal import no_leftovers, same_content
from tests.test_kill_points import EACH, OPEN, ROOT, TASK, _command, killed_at, record_reference

# four episodes: two shards of two, a conversion's data file open at its third, two halves of two to merge
EPISODES = 4


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    return record_reference(tmp_path_factory, EPISODES)


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "kitbench.cli", *args]


def _ok(cmd: list[str]) -> subprocess.CompletedProcess:
    run = launch.run(cmd, env={**os.environ, "HF_HUB_OFFLINE": "1"}, cwd=ROOT, timeout=600, text=True)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "Traceback" not in run.stderr
    return run


# case -> the fault point and the workers. The points are the driver's: shards recorded in the driver's own
# process (one worker) reach them as a pool's do, without two interpreters started for each run. On a pool of
# two, the second shard in flight when the first is stored, is a variant run by make test-all and CI (a pool's
# sharded recording stopped and resumed is in test_shards.py).
SHARDED = {
    "a shard half unpacked into the journal": ("shards.extracting:2", 1),
    "the shards merged, not in place": ("shards.merged:1", 1),
    "the merge in place, the shards still journaled": ("shards.swapped:1", 1),
}
SHARDED_CASES = [
    *(pytest.param(*case, id=name) for name, case in SHARDED.items()),
    pytest.param("shards.extracting:2", 2, id="a shard half unpacked, on a pool of two", marks=pytest.mark.slow),
]


@pytest.mark.parametrize(("fault", "workers"), SHARDED_CASES)
def test_a_sharded_recording_killed_at_a_fault_point_resumes_into_one_writers_recording(
    tmp_path, reference, fault, workers
):
    out = tmp_path / "ds"
    sharded = ["--shard-episodes", "2", "--workers", str(workers)]
    killed_at([*_command(out, OPEN, False, EPISODES), *sharded], fault)
    _ok([*_command(out, OPEN, True, EPISODES), *sharded])
    same_content(reference, out)
    no_leftovers(out)


@pytest.fixture(scope="module")
def converted(tmp_path_factory, reference) -> Path:
    out = tmp_path_factory.mktemp("converted") / "ds"
    _ok(_cli("convert", str(reference), "--out", str(out), "--control-mode", "pd_joint_pos"))
    return out


@pytest.mark.parametrize(
    ("interval", "fault"),
    [(OPEN, "writer.saved:3"), (EACH, "commit.retired:2")],
    ids=["a data file open", "the dataset set aside"],
)
def test_a_conversion_killed_at_a_fault_point_resumes_into_the_uninterrupted_one(
    tmp_path, reference, converted, interval, fault
):
    out = tmp_path / "ds"
    convert = _cli(
        "convert",
        str(reference),
        "--out",
        str(out),
        "--control-mode",
        "pd_joint_pos",
        "--commit-interval",
        str(interval),
    )
    killed_at(convert, fault)
    _ok([*convert, "--resume"])
    same_content(converted, out)
    no_leftovers(out)


def _eval_save(reference: Path, report: Path, dataset: Path, *extra: str) -> list[str]:
    return _cli(
        "eval",
        "--task",
        TASK,
        "--seed",
        "0",
        "--episodes",
        "3",
        "--policy",
        f"replay:{reference}",
        "--out",
        str(report),
        "--save-dataset",
        str(dataset),
        *extra,
    )


@pytest.fixture(scope="module")
def saved(tmp_path_factory, reference) -> Path:
    folder = tmp_path_factory.mktemp("saved")
    _ok(_eval_save(reference, folder / "report", folder / "ds"))
    return folder / "ds"


@pytest.fixture(scope="module")
def saved_before(tmp_path_factory, reference) -> Path:
    """The existing dataset each case saves over: two episodes saved by the same command."""
    folder = tmp_path_factory.mktemp("saved_before")
    _ok(_eval_save(reference, folder / "report", folder / "ds", "--episodes", "2"))
    return folder / "ds"


@pytest.mark.parametrize("fault", ["writer.saved:2", "commit.card:1", "commit.retired:1"])
def test_an_evaluation_killed_while_saving_its_dataset_leaves_the_old_one_or_the_new_one_whole(
    tmp_path, reference, saved, saved_before, fault
):
    """Saved over an existing dataset (--overwrite): a kill leaves it as it was or the new one whole, never
    neither; the same command again writes the new one."""
    dataset = tmp_path / "ds"
    shutil.copytree(saved_before, dataset)
    assert [e.seed for e in read_episodes(dataset)] == [0, 1]
    killed_at(_eval_save(reference, tmp_path / "report", dataset, "--overwrite"), fault)
    recover(dataset)
    seeds = [e.seed for e in read_episodes(dataset)]
    assert seeds in ([0, 1], [0, 1, 2])  # the old dataset, or the new one whole
    _ok(_eval_save(reference, tmp_path / "report", dataset, "--overwrite"))
    same_content(saved, dataset)
    no_leftovers(dataset)


@pytest.fixture(scope="module")
def halves(tmp_path_factory) -> tuple[Path, Path, Path]:
    folder = tmp_path_factory.mktemp("halves")
    a, b, merged = folder / "a", folder / "b", folder / "merged"
    record(RecordConfig.of(task=TASK, episodes=EPISODES // 2, out=a), progress=False)
    record(RecordConfig.of(task=TASK, episodes=EPISODES // 2, seed=EPISODES // 2, out=b), progress=False)
    _ok(_cli("merge", str(a), str(b), "--out", str(merged)))
    return a, b, merged


@pytest.mark.parametrize("fault", ["merge.aggregated:1", "merge.retired:1"])
def test_a_merge_killed_at_a_fault_point_leaves_nothing_and_runs_again(tmp_path, halves, fault):
    a, b, merged = halves
    out = tmp_path / "merged"
    shutil.copytree(merged, out)  # an earlier merge, replaced below
    killed_at(_cli("merge", str(a), str(b), "--out", str(out), "--overwrite"), fault)
    _ok(_cli("merge", str(a), str(b), "--out", str(out), "--overwrite"))
    same_content(merged, out)
    no_leftovers(out)
