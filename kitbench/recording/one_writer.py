"""Recording on one writer (`record_episodes`): episodes run on the rollout engine (`kitbench.engine`: this process,
a local process pool, or Ray actors) and reach the recording session (`session.RecordingSession`) in seed order, so a
dataset depends only on its settings, not on where it was recorded. `kitbench record` without shards runs it, and so
does each shard of a sharded recording, in its worker."""

from __future__ import annotations

import itertools
import sys
import time
from collections.abc import Iterator
from contextlib import ExitStack
from pathlib import Path

from kitbench import faults
from kitbench.engine import RolloutEngine, make_executor
from kitbench.metadata import EpisodeInfo, lerobot_info
from kitbench.recording.config import RecordConfig, make_recording_env
from kitbench.recording.rollout import EpisodeRecord
from kitbench.recording.run import RecordingRun
from kitbench.recording.session import RecordingSession, dataset_state
from kitbench.recording.stops import StopSignals
from kitbench.recording.summary import Summary
from kitbench.recording.work import RecordWork
from kitbench.rollout import Control

STOPPED = "stopped as asked (escape): the episodes stored are committed; continue with --resume"


def _say(message: str) -> None:
    print(f"kitbench record: {message}", file=sys.stderr, flush=True)


def open_session(config: RecordConfig) -> RecordingSession:
    """The recording's session, with the features, fps and robot read off the env (the one place they are
    defined)."""
    from kitbench.recording.features import dataset_features

    env = make_recording_env(config)
    try:
        env.reset(seed=config.demo.seed)
        features = dataset_features(env, config.env.pointcloud_points, config.output.rgb_storage)
        fps, robot = env.control_freq, env.robot_uid
    finally:
        env.close()
    if not config.output.overwrite:
        features = started_with(config.out, features)
    info = config.info(fps=fps)
    return RecordingSession(config.out, info, features, robot, config.output.commit_interval)


def started_with(out: Path, features: dict) -> dict:
    """The features a resumed dataset at `out` was started with: one recorded before the cameras' parameters were
    stored goes on without them (all of `features` for a new dataset)."""
    stored = lerobot_info(out).get("features")
    if stored is None:
        return features
    return {name: feature for name, feature in features.items() if name in stored}


def record_episodes(config: RecordConfig, progress: bool = True, signals: bool = True) -> Summary:
    """Record on one writer (`config` already validated). Workers start before anything is written or replaced:
    a run whose workers cannot start (a Ray cluster short of CPUs) leaves everything as it was."""
    started = time.monotonic()  # the speed printed counts the workers' start-up, as a user waits for it
    committed, journaled = dataset_state(config.out, config.output.overwrite, _say)
    with ExitStack() as workers:
        engine = None
        to_record = config.episodes - len(committed) - len(journaled)
        if to_record > 0:
            executor = make_executor(config.executor, jobs=to_record)
            engine = workers.enter_context(RolloutEngine(executor, RecordWork(config)))
        session = open_session(config)
        session.start(overwrite=config.output.overwrite)
        faults.point("record.started")
        summary = Recording(config, session, committed, progress).run(engine, signals)
    return summary.measured(started, config.out)


class Recording(RecordingRun):
    """One writer's recording: what the journal held first, then new episodes from the engine, each stored as it
    arrives and committed periodically; a stop commits what is stored."""

    def __init__(self, config: RecordConfig, session: RecordingSession, committed: list[EpisodeInfo], progress: bool):
        super().__init__(config, Summary(stored=len(committed)), progress)
        self.session = session
        self.done_seeds = {e.seed for e in committed}

    def run(self, engine: RolloutEngine | None, signals: bool = True) -> Summary:
        super().run(engine, signals)
        if self.summary.stored >= self.config.episodes or (
            self.config.source is not None and not self.summary.interrupted
        ):
            self.session.finish()  # a conversion is done when every source seed was tried, stored or not
        return self.summary

    def _record(self, engine: RolloutEngine | None, stops: StopSignals) -> None:
        replayed = self._republish(stops)
        remaining = self.config.episodes - self.summary.stored
        if remaining > 0 and engine is not None:
            self._open_bar(remaining, f"record {self.config.task}")
            self._record_new(engine, stops, replayed)
        with stops.storing():
            self.session.commit()

    def _stopped(self) -> None:
        self.session.commit()

    def _abandon(self) -> None:
        self.session.abandon()  # the journal keeps every finished episode for --resume

    def _republish(self, stops: StopSignals) -> list[int]:
        """Episodes a killed run had finished but not committed, published first, in seed order, and committed at
        once: a run killed again before its first commit would otherwise replay them all again, and kills coming
        faster than the replay would stall the recording."""
        replayed: list[int] = []
        for seed in self.session.journaled():
            if self.summary.stored >= self.config.episodes:
                break
            with stops.storing():
                self.session.republish(seed)
                replayed.append(seed)
                self.summary.stored += 1
            faults.point("resume.republish")
        if replayed:
            with stops.storing():
                self.session.commit()
        return replayed

    def _seeds(self, replayed: list[int]) -> Iterator[int]:
        """The seeds still to run: consecutive after the last stored, or a conversion's source seeds not yet
        stored."""
        done = {*self.done_seeds, *replayed}
        if self.config.source is None:
            last = max(done, default=self.config.demo.seed - 1)
            return itertools.count(max(last + 1, self.config.demo.seed))
        from kitbench.recording.source import SourceRecording

        return iter([s for s in SourceRecording(self.config.source).seeds if s not in done])

    def _record_new(self, engine: RolloutEngine, stops: StopSignals, replayed: list[int]) -> None:
        summary, bar = self.summary, self.bar

        def needed() -> int:  # in flight: never more episodes than are still needed or may still be attempted
            return min(self.config.episodes - summary.stored, self.limit - summary.attempted)

        for _, (episode, mcap) in engine.results(self._seeds(replayed), needed):
            if episode.control is Control.STOP and not episode.length:  # stopped before the episode began
                _say(STOPPED)
                break
            summary.attempted += 1
            summary.successes += int(episode.success)
            if self._keep(episode):
                with stops.storing():
                    self.session.store(episode, mcap)
                    summary.stored += 1
                    summary.frames += episode.length
                if bar is not None:
                    bar.update(1)
                if self.session.commit_due():
                    with stops.storing():  # a commit interrupted half-way would leave a session to discard
                        self.session.commit()
            if bar is not None:
                bar.set_postfix(success=f"{summary.successes / summary.attempted:.0%}", tried=summary.attempted)
            if summary.should_stop(self.config.episodes, self.limit):
                break
            if episode.control is Control.STOP:  # a person's escape: stored as any episode, then the end
                _say(STOPPED)
                break

    def _keep(self, episode: EpisodeRecord) -> bool:
        """Whether to store the episode: never one whose simulation failed or that diverged from its source, and
        with only_success a success only."""
        if episode.physics_error is not None:
            self.summary.physics_errors += 1
            _say(f"seed {episode.seed}: not stored, the simulation failed: {episode.physics_error}")
            return False
        if episode.rejected is not None:
            self.summary.rejected += 1
            _say(f"seed {episode.seed}: not stored, {episode.rejected}")
            return False
        if self.config.demo.only_success and not episode.success:
            self.summary.failures_dropped += 1
            return False
        return True
