"""A recording session: episodes going into one LeRobot dataset, each durable before the next (the journal),
published at commits (the LeRobot writer), resumable after a kill. `kitbench record` (and each shard of a sharded
recording, and `kitbench convert`) stores its episodes through one; `kitbench eval --save-dataset` through one
without a journal, committed once.

Order of events for an episode: its MCAP log and frames go to the journal (fsync'd), then into the open LeRobot
session with the log linked beside it; a commit (every `commit_interval` seconds, and at the end) publishes the
session and drops its journal entries. A kill loses at most the episode in flight; `resume` publishes what the
journal holds, in seed order, before recording goes on.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

from kitbench import faults
from kitbench.metadata import EpisodeInfo, RecordingInfo, read_episodes
from kitbench.recording.dataset import DatasetWriter, recover, remove_recording
from kitbench.recording.journal import EpisodeJournal
from kitbench.recording.rollout import EpisodeRecord

MCAP_DIR = "mcap"


def dataset_state(out: Path, overwrite: bool, say: Callable[[str], None]) -> tuple[list[EpisodeInfo], list[int]]:
    """Before a recording at `out` starts: the episodes its dataset holds and the seeds its journal holds beyond
    them. A commit a kill interrupted is completed or undone first; with `overwrite`, there is nothing to keep.
    A damaged journal entry (`say` tells which) is recorded again, with those after it."""
    if overwrite:
        return [], []
    recover(out)
    committed = read_episodes(out) if out.exists() else []
    journal = EpisodeJournal(out)
    done = {e.seed for e in committed}
    journal.discard([s for s in journal.seeds() if s in done])  # published just before a kill
    seeds, damage = journal.check()
    if damage is not None:
        say(damage)
    return committed, seeds


class RecordingSession:
    """The dataset at `out`, open for episodes."""

    def __init__(
        self,
        out: Path,
        info: RecordingInfo,
        features: dict,
        robot: str,
        commit_interval: float,
        durable: bool = True,
        replace: bool = False,
    ):
        """`durable`: each episode journaled before it is published (else committed only, once, at the end);
        `replace`: the first commit replaces a dataset at `out` whole, which stays as it was until then."""
        self.out = Path(out)
        self.info = info
        self.writer = DatasetWriter(self.out, info, features, robot, replace)
        self.journal = EpisodeJournal(self.out) if durable else None
        self.commit_interval = commit_interval
        self.published: list[int] = []  # seeds in the open session, journaled until it is committed

    def start(self, overwrite: bool = False) -> None:
        """Before the first episode: replace what `overwrite` replaces, keep the settings in the journal."""
        if overwrite:
            remove_recording(self.out)
        self.out.parent.mkdir(parents=True, exist_ok=True)
        if self.journal is not None:
            self.journal.start(self.info)

    def publish(self, episode: EpisodeRecord, log: Path | None) -> None:
        """Add an episode (durable already, or in a session without a journal) to the open session, its MCAP log
        (`log`, in the journal) linked beside it."""
        index = self.writer.add_episode(episode)
        if log is not None:  # linked: the journal keeps its copy until the commit publishes the session
            target = self.writer.session_root / MCAP_DIR / f"episode_{index:06d}.mcap"
            target.parent.mkdir(parents=True, exist_ok=True)
            os.link(log, target)
        self.published.append(episode.seed)
        faults.point("session.published")

    def store(self, episode: EpisodeRecord, mcap: bytes | None = None) -> None:
        """Make `episode` durable, then add it to the open session."""
        if self.journal is None:
            if mcap is not None:
                raise ValueError("a session without a journal stores no MCAP logs")
            self.publish(episode, None)
            return
        log = self.journal.add(episode, mcap)
        faults.point("journal.added")
        self.publish(episode, log)

    def journaled(self) -> list[int]:
        return self.journal.seeds() if self.journal is not None else []

    def republish(self, seed: int) -> EpisodeRecord:
        """A journaled episode a killed run had finished, added to the open session."""
        assert self.journal is not None
        episode, log = self.journal.load(seed)
        self.publish(episode, log)
        return episode

    def commit_due(self) -> bool:
        return self.writer.session_age() >= self.commit_interval

    def commit(self) -> None:
        """Publish the open session and forget its journaled episodes."""
        self.writer.commit()
        faults.point("commit.done")
        if self.journal is not None:
            self.journal.discard(self.published)
        self.published.clear()

    def abandon(self) -> None:
        """Drop the open session (the journal keeps every finished episode for a resume)."""
        self.writer.abandon()

    def finish(self) -> None:
        """The recording is complete: its journal goes."""
        if self.journal is not None:
            faults.point("record.finishing")
            self.journal.remove()
