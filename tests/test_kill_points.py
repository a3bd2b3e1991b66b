"""A recording killed at any moment of its life resumes into the recording an uninterrupted run makes.

Each case kills `kitbench record` with SIGKILL at a named fault point (`kitbench.faults`: the process kills
itself the nth time it passes the point, so moments a wall-clock kill almost never hits, inside a commit or
between its two renames, are reached every time), resumes it, and compares the result with an uninterrupted
recording of the same seeds: every data column, the episode metadata, the settings, the MCAP logs byte for byte,
nothing left beside the dataset. Killing at wall-clock moments, and the other writers (shards, convert, eval
--save-dataset, merge), are in test_durability.py, test_ray_executor.py and test_kill_points_writers.py.
"""

from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest

import kitbench  # noqa: F401
from kitbench import faults
from kitbench.errors import KitbenchError
from kitbench.recording.journal import journal_root
from kitbench.recording.recorder import RecordConfig, record
from tests import launch
from tests.datasets_equal import no_leftovers, same_content
from tests.processes import record_command

ROOT = Path(__file__).resolve().parents[1]
TASK = "LiftPegUpright-v1"
# LeRobot buffers episode metadata ten episodes at a time: past ten, a session has an episode index on disk whose
# data file has no footer yet, the state the first report of a failing resume was in.
EPISODES = 12
# Every other point is passed within the first four episodes (with a commit after every episode, within the first
# three commits): four episodes do, most cases killed with an episode left for the resume to record.
EACH_EPISODES = 4
OPEN = 30.0  # commit interval that keeps one session open for the whole recording
EACH = 0.0  # a commit after every episode

# case -> the commit interval, the episodes recorded, and the fault point each killed run stops at (a second one:
# killed again while resuming); the passes counted are the run's own.
CASES: dict[str, tuple[float, int, list[str]]] = {
    "before the first episode": (OPEN, EACH_EPISODES, ["record.started"]),
    "the journal's settings half written": (OPEN, EACH_EPISODES, ["journal.write:1"]),
    "an MCAP log half written to the journal": (OPEN, EACH_EPISODES, ["journal.write:4"]),
    "an episode half written to the journal": (OPEN, EACH_EPISODES, ["journal.write:5"]),
    "journaled, not yet in the session": (OPEN, EACH_EPISODES, ["journal.added:3"]),
    "half an episode in LeRobot's buffer": (OPEN, EACH_EPISODES, ["writer.frames:2"]),
    "the first data file open": (OPEN, EACH_EPISODES, ["writer.saved:1"]),
    "a data file open beside an episode index": (OPEN, EPISODES, ["writer.saved:11"]),
    "an MCAP log linked into the session": (OPEN, EACH_EPISODES, ["session.published:4"]),
    "a session finalized": (EACH, EACH_EPISODES, ["commit.finalized:3"]),
    "kitbench's metadata written": (EACH, EACH_EPISODES, ["commit.metadata:2"]),
    "the first commit complete, not in place": (EACH, EACH_EPISODES, ["commit.card:1"]),
    "a commit complete, not in place": (EACH, EACH_EPISODES, ["commit.card:3"]),
    "the dataset set aside": (EACH, EACH_EPISODES, ["commit.retired:2"]),
    "the first commit in place": (EACH, EACH_EPISODES, ["commit.swapped:1"]),
    "a commit in place, the old dataset not deleted": (EACH, EACH_EPISODES, ["commit.swapped:3"]),
    "committed, its episodes still journaled": (EACH, EACH_EPISODES, ["commit.done:3"]),
    "the journal half trimmed": (EACH, EACH_EPISODES, ["journal.discard:3"]),
    "the last commit made, the journal being deleted": (OPEN, EACH_EPISODES, ["record.finishing"]),
    "killed again while republishing": (OPEN, EPISODES, ["writer.saved:8", "resume.republish:3"]),
    "killed at a commit, then inside the next": (EACH, EACH_EPISODES, ["commit.retired:1", "commit.finalized:2"]),
}


def record_reference(tmp_path_factory, episodes: int = EPISODES) -> Path:
    """The uninterrupted recording the killed ones are compared with."""
    out = tmp_path_factory.mktemp("reference") / "ds"
    record(RecordConfig.of(task=TASK, episodes=episodes, out=out), progress=False)
    return out


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    return record_reference(tmp_path_factory)


@pytest.fixture(scope="module")
def short_reference(tmp_path_factory) -> Path:
    return record_reference(tmp_path_factory, EACH_EPISODES)


def _command(out: Path, interval: float, resume: bool, episodes: int = EPISODES) -> list[str]:
    flags = [
        "--episodes",
        str(episodes),
        "--commit-interval",
        str(interval),
        *(["--resume"] if resume else []),
    ]
    return record_command(out, TASK, *flags)


def killed_at(cmd: list[str], fault: str) -> None:
    """Run `cmd` with the fault point armed; it must die there, by SIGKILL."""
    env = {**os.environ, "HF_HUB_OFFLINE": "1", faults.VAR: fault}
    env.pop(faults.OWNER_VAR, None)
    run = launch.run(cmd, env=env, cwd=ROOT, timeout=600, text=True)
    assert run.returncode == -signal.SIGKILL, f"{fault} was not reached (exit {run.returncode}): {run.stderr[-2000:]}"


@pytest.mark.parametrize(("interval", "episodes", "kills"), CASES.values(), ids=CASES.keys())
def test_a_recording_killed_at_a_fault_point_resumes_into_the_uninterrupted_one(
    tmp_path, request, interval, episodes, kills
):
    reference = request.getfixturevalue("reference" if episodes == EPISODES else "short_reference")
    out = tmp_path / "ds"
    for i, fault in enumerate(kills):
        killed_at(_command(out, interval, i > 0, episodes), fault)
    assert out.exists() or journal_root(out).exists()  # something to resume
    summary = record(
        RecordConfig.of(task=TASK, episodes=episodes, out=out, commit_interval=interval, resume=True), progress=False
    )
    assert summary.stored == episodes
    same_content(reference, out)
    no_leftovers(out)


def test_every_fault_point_is_passed_somewhere_in_the_code():
    """A point named in `faults.POINTS` that no code passes would make a case above test nothing."""
    code = "\n".join(p.read_text() for p in (ROOT / "kitbench").rglob("*.py") if p.name != "faults.py")
    missing = [name for name in faults.POINTS if f'faults.point("{name}")' not in code]
    assert not missing, missing


def test_a_bad_fault_value_is_one_line_naming_the_points(tmp_path):
    env = {**os.environ, faults.VAR: "commit.nowhere:2"}
    run = launch.run(record_command(tmp_path / "x", TASK, "--episodes", "1"), env=env, cwd=ROOT, timeout=300, text=True)
    assert run.returncode == 2
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and "'commit.nowhere'" in lines[0] and "commit.retired" in lines[0]
    assert not (tmp_path / "x").exists() and not journal_root(tmp_path / "x").exists()
    with pytest.raises(KitbenchError, match="whole number"):
        faults.parse("commit.card:0")
