"""Sharded recording (`--shard-episodes`): workers write whole shards, merged at the end into the dataset one
writer makes of the same seeds, on a local pool and on Ray; a sharded recording resumes and extends; bad
settings are refused; a run ended by a lost cluster or a signal keeps its journal and says so."""

from __future__ import annotations

import os
import signal

import pytest

from kitbench.engine.executor import ClusterLost
from kitbench.errors import KitbenchError
from kitbench.recording.journal import EpisodeJournal, journal_root
from kitbench.recording.recorder import RecordConfig, record
from kitbench.recording.shards import ShardedRecording
from kitbench.recording.stops import Stopped
from tests import launch
from tests.test_merge import _assert_same_recording, _frames

os.environ.setdefault("HF_HUB_OFFLINE", "1")
TASK = "LiftPegUpright-v1"
EPISODES = 5


@pytest.fixture(scope="module")
def one_writer(tmp_path_factory):
    out = tmp_path_factory.mktemp("one") / "lpu"
    record(RecordConfig.of(task=TASK, episodes=EPISODES, out=out), progress=False)
    return out


def test_shards_on_a_pool_merge_into_the_one_writer_dataset(one_writer, tmp_path):
    out = tmp_path / "lpu"
    summary = record(
        RecordConfig.of(task=TASK, episodes=EPISODES, out=out, workers=2, shard_episodes=2), progress=False
    )
    assert (summary.stored, summary.attempted, summary.frames) == (EPISODES, EPISODES, len(_frames(one_writer)))
    _assert_same_recording(one_writer, out)
    assert not journal_root(out).exists()  # the shards are merged and gone


def test_a_sharded_recording_resumes_and_extends(one_writer, tmp_path):
    out = tmp_path / "lpu"
    record(RecordConfig.of(task=TASK, episodes=2, out=out, shard_episodes=2), progress=False)
    record(RecordConfig.of(task=TASK, episodes=EPISODES, out=out, shard_episodes=2, resume=True), progress=False)
    _assert_same_recording(one_writer, out)


def test_a_sharded_journal_is_not_resumed_without_shards(tmp_path):
    out = tmp_path / "lpu"
    (journal_root(out) / "shards").mkdir(parents=True)
    (journal_root(out) / "recording.json").write_text("{}")
    with pytest.raises(KitbenchError, match=r"is an unfinished sharded recording; resume it with --shard-episodes"):
        record(RecordConfig.of(task=TASK, episodes=2, out=out, resume=True), progress=False)


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        ({"shard_episodes": -1}, "shard_episodes must be an integer >= 0, got -1"),
        ({"shard_episodes": 2, "only_success": True}, "shard_episodes and only_success exclude each other"),
    ],
)
def test_bad_shard_settings_are_refused_before_anything_is_written(tmp_path, settings, message):
    with pytest.raises(KitbenchError) as err:
        record(RecordConfig.of(task=TASK, episodes=2, out=tmp_path / "lpu", **settings), progress=False)
    assert str(err.value).startswith(message) and "\n" not in str(err.value)
    assert list(tmp_path.iterdir()) == []


def test_sigterm_stops_a_sharded_pool_recording_promptly_and_resume_finishes(tmp_path):
    """Shards recorded inside pool workers leave signals to the pool: SIGTERM ends the run (the pool's own SIGTERM
    then ends the workers mid-shard), the stored shards stay, and --resume completes the seeds in order."""
    import json
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "lpu"
    # three shards on two workers: the third is under way when the first is stored
    command = [sys.executable, "-m", "kitbench.cli", "record", "--task", TASK, "--episodes", "6", "--out", str(out)]
    command += ["--workers", "2", "--shard-episodes", "2", "--no-mcap"]
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    shards = journal_root(out) / "shards"
    deadline = time.monotonic() + 240
    while proc.poll() is None and not list(shards.glob("shard-*")) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert proc.poll() is None, "the recording ended before it could be stopped"
    proc.send_signal(signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=60)  # no worker left waiting: a hang fails here
    assert proc.returncode == 128 + signal.SIGTERM, stderr[-2000:]
    assert "continue with --resume" in stdout and list(shards.glob("shard-*"))
    launch.run([*command, "--resume"], check=True, capture_output=True, timeout=300)
    seeds = [json.loads(line)["seed"] for line in (out / "meta/kitbench_episodes.jsonl").read_text().splitlines()]
    assert seeds == list(range(6))


class _EndsEarly:
    """An engine whose first shard never comes back: the cluster goes, or a signal arrives, while it runs."""

    def __init__(self, error: BaseException):
        self.error = error

    def results(self, jobs, needed):
        next(iter(jobs))  # the first shard handed out
        raise self.error
        yield  # a generator, as the engine's results are


@pytest.mark.parametrize(
    "error", [ClusterLost("the Ray cluster at 127.0.0.1:1 was lost"), Stopped(signal.SIGTERM)], ids=["lost", "SIGTERM"]
)
def test_a_sharded_run_ended_early_keeps_its_journal_and_says_resume(tmp_path, error):
    config = RecordConfig.of(task=TASK, episodes=4, out=tmp_path / "lpu", shard_episodes=2)
    run = ShardedRecording(config, EpisodeJournal(config.out), [], progress=False)
    if isinstance(error, ClusterLost):
        with pytest.raises(KitbenchError) as err:
            run.run(_EndsEarly(error), signals=False)
        assert str(err.value) == (
            "the Ray cluster at 127.0.0.1:1 was lost; every shard finished before is kept: continue with --resume"
        )
    else:
        summary = run.run(_EndsEarly(error), signals=False)
        assert summary.interrupted and summary.exit_code == 128 + signal.SIGTERM and summary.stored == 0
    assert journal_root(config.out).is_dir() and not config.out.exists()
