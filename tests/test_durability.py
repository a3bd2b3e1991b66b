"""Recording survives what a cluster or a user does to it: kill -9 loses at most the episode in flight, SIGTERM
and SIGHUP commit like Ctrl-C, a run that cannot reach its episode count stops, and nothing is left behind."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import time
from pathlib import Path

import pandas as pd
import pytest

import kitbench  # noqa: F401
from kitbench.recording.journal import EpisodeJournal, journal_root
from kitbench.recording.recorder import RecordConfig, record
from tests import launch
from tests.datasets_equal import same_content
from tests.processes import record_command

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "HF_HUB_OFFLINE": "1", "PYTHONUNBUFFERED": "1"}
TASK = "LiftPegUpright-v1"
# enough episodes that three kills a few episodes apart, and one past ten episodes in one session (LeRobot's episode
# index on disk beside a data file it still has open), each stop a run that has not finished
EPISODES = 24


def _cli(out: Path, *args: str) -> list[str]:
    return record_command(out, TASK, *args)


def _wait_for_journal(out: Path, count: int, proc: subprocess.Popen, timeout: float = 240.0) -> int:
    """Block until the running recording has journaled `count` episodes; returns how many it has."""
    deadline = time.monotonic() + timeout
    root = journal_root(out)
    while time.monotonic() < deadline:
        n = len(list(root.glob("seed-*.npz")))
        if n >= count:
            return n
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.05)
    raise AssertionError(f"no {count} journaled episodes after {timeout} s")


def _dataset(out: Path) -> tuple[pd.DataFrame, list[dict]]:
    frames = pd.concat([pd.read_parquet(p) for p in sorted((out / "data").rglob("*.parquet"))])
    episodes = [json.loads(line) for line in (out / "meta/kitbench_episodes.jsonl").read_text().splitlines()]
    return frames.reset_index(drop=True), episodes


def _assert_same_dataset(a: Path, b: Path) -> None:
    same_content(a, b)


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    """An uninterrupted recording that interrupted ones must end up equal to."""
    out = tmp_path_factory.mktemp("reference") / "ds"
    record(RecordConfig.of(task=TASK, episodes=EPISODES, out=out, commit_interval=30.0), progress=False)
    return out


def test_kill_9_loses_at_most_the_episode_in_flight(tmp_path, reference):
    out = tmp_path / "ds"
    rng = random.Random(7)
    for _ in range(3):  # killed at three moments, resumed each time
        resume = ["--resume"] if out.exists() or journal_root(out).exists() else []
        proc = launch.start(_cli(out, "--episodes", str(EPISODES), *resume), env=ENV, cwd=ROOT, logs=tmp_path)
        before = len(EpisodeJournal(out).seeds()) if journal_root(out).exists() else 0
        journaled = _wait_for_journal(out, before + rng.randint(2, 6), proc)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        # the 30 s default commit interval has not passed: the journal holds every finished episode
        assert len(EpisodeJournal(out).seeds()) >= journaled
    kept = len(EpisodeJournal(out).seeds()) + (len(_dataset(out)[1]) if out.exists() else 0)
    done = launch.run(_cli(out, "--episodes", str(EPISODES), "--resume"), env=ENV, cwd=ROOT, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    assert f"attempted {EPISODES - kept}," in done.stdout  # nothing that was journaled is recorded again
    assert not journal_root(out).exists()
    _assert_same_dataset(out, reference)


def test_kill_9_while_a_data_file_is_open_then_resume_gives_the_uninterrupted_recording(tmp_path, reference):
    """The first report: `kill -9` once LeRobot had written an episode index beside a data file it still had open
    (more than ten episodes in the session), then `--resume`, ended in pyarrow's 'Parquet magic bytes not found'."""
    out = tmp_path / "ds"
    proc = launch.start(
        _cli(out, "--episodes", str(EPISODES), "--commit-interval", "600"), env=ENV, cwd=ROOT, logs=tmp_path
    )
    _wait_for_journal(out, 14, proc)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not out.exists() and list((tmp_path / "ds.session" / "meta" / "episodes").rglob("*.parquet"))
    done = launch.run(_cli(out, "--episodes", str(EPISODES), "--resume"), env=ENV, cwd=ROOT, text=True, timeout=600)
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr[-2000:]
    _assert_same_dataset(out, reference)
    assert not (tmp_path / "ds.session").exists() and not journal_root(out).exists()


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP], ids=["SIGTERM", "SIGHUP"])
def test_sigterm_and_sighup_commit_like_ctrl_c(tmp_path, signum):
    out = tmp_path / "ds"
    proc = launch.start(_cli(out, "--episodes", "200", "--workers", "2"), env=ENV, cwd=ROOT, logs=tmp_path)
    journaled = _wait_for_journal(out, 3, proc)
    proc.send_signal(signum)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 128 + signum, stderr[-2000:]
    assert f"interrupted ({signal.Signals(signum).name}): every completed episode was committed" in stdout
    assert len(_dataset(out)[1]) >= journaled  # committed, loadable
    assert not list(tmp_path.glob(".ds.mcap-*")) and not (tmp_path / "ds.session").exists()


def test_only_success_stops_at_the_attempt_limit(tmp_path, capsys):
    from kitbench.cli import main

    out = tmp_path / "ds"
    code = main(
        [
            "record",
            "--task",
            TASK,
            "--out",
            str(out),
            "--episodes",
            "1",
            "--policy",
            "random",
            "--only-success",
            "--max-attempts",
            "3",
        ]
    )
    assert code == 3
    text = capsys.readouterr().out
    assert "stopped after 3 attempts (0 successes, success rate 0.0%)" in text and "--max-attempts" in text
    assert not list(tmp_path.glob(".ds.mcap-*"))  # its temporary MCAP folder is gone


def test_default_attempt_limit_is_ten_per_episode(tmp_path):
    summary = record(
        RecordConfig.of(task=TASK, episodes=1, out=tmp_path / "ds", policy="random", only_success=True, mcap=False),
        progress=False,
    )
    assert summary.gave_up and summary.attempted == 10 and summary.stored == 0 and summary.exit_code == 3


def test_a_fresh_recording_never_replays_a_stale_journal(tmp_path):
    out = tmp_path / "ds"
    record(RecordConfig.of(task=TASK, episodes=2, out=out, mcap=False), progress=False)
    journal = EpisodeJournal(out)
    assert not journal.exists()  # complete: nothing left to replay
    record(RecordConfig.of(task=TASK, episodes=1, out=tmp_path / "other", seed=50, mcap=False), progress=False)
    _, episodes = _dataset(tmp_path / "other")
    assert [e["seed"] for e in episodes] == [50]


def test_recording_leaks_no_files_or_descriptors(tmp_path):
    def open_fds() -> int:
        return len(os.listdir("/proc/self/fd"))

    record(RecordConfig.of(task=TASK, episodes=1, out=tmp_path / "warm", mcap=True), progress=False)
    before = open_fds()
    for i in range(3):
        record(RecordConfig.of(task=TASK, episodes=1, out=tmp_path / f"ds{i}", mcap=True), progress=False)
    assert open_fds() <= before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds0", "ds1", "ds2", "warm"]


def test_a_journal_with_episodes_is_never_overwritten_by_accident(tmp_path):
    from kitbench.errors import KitbenchError

    out = tmp_path / "ds"
    proc = launch.start(_cli(out, "--episodes", "50", "--no-mcap"), env=ENV, cwd=ROOT, logs=tmp_path)
    _wait_for_journal(out, 2, proc)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    with pytest.raises(KitbenchError, match=r"an unfinished recording of .*ds exists .*ds.journal.*pass --resume"):
        record(RecordConfig.of(task=TASK, episodes=5, out=out, mcap=False), progress=False)
    with pytest.raises(KitbenchError, match=r"cannot resume .* different settings .*control_mode"):
        record(
            RecordConfig.of(task=TASK, episodes=5, out=out, mcap=False, resume=True, control_mode="pd_ee_delta_pose"),
            progress=False,
        )
    summary = record(RecordConfig.of(task=TASK, episodes=5, out=out, mcap=False, resume=True), progress=False)
    assert summary.stored == 5 and [e["seed"] for e in _dataset(out)[1]] == [0, 1, 2, 3, 4]


def test_an_episode_whose_simulation_failed_is_not_stored(tmp_path, monkeypatch, capsys):
    from kitbench.envs.tabletop import TabletopEnv

    reset, step = TabletopEnv.reset, TabletopEnv.step

    def reset_noting_the_seed(self, *, seed=None, options=None):
        self.test_seed = seed
        return reset(self, seed=seed, options=options)

    def step_failing_on_seed_1(self, action):
        obs, reward, terminated, truncated, info = step(self, action)
        if self.test_seed == 1 and self.elapsed_steps == 3:
            return obs, 0.0, False, True, {**info, "success": False, "physics_error": "obj left the workspace"}
        return obs, reward, terminated, truncated, info

    monkeypatch.setattr(TabletopEnv, "reset", reset_noting_the_seed)
    monkeypatch.setattr(TabletopEnv, "step", step_failing_on_seed_1)
    out = tmp_path / "ds"
    summary = record(RecordConfig.of(task=TASK, episodes=3, out=out), progress=False)
    assert summary.physics_errors == 1 and summary.stored == 3 and summary.attempted == 4
    assert "seed 1: not stored, the simulation failed: obj left the workspace" in capsys.readouterr().err
    assert [e["seed"] for e in _dataset(out)[1]] == [0, 2, 3]
    assert sorted(p.name for p in (out / "mcap").iterdir()) == [f"episode_{i:06d}.mcap" for i in range(3)]
    assert any("simulation failed: 1 attempt(s)" in line for line in summary.lines(out))
