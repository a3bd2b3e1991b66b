"""Sharded recording (`kitbench record --shard-episodes N`): each worker records whole shards, N consecutive seeds
into a LeRobot dataset of its own, and the driver merges the shards with LeRobot's aggregation at the end.

Why: one writer commits at most ~350 state or ~120 rgb episodes/min on this machine (`bench/record_throughput.py`:
lerobot's `add_episode` costs ~170 ms a state episode, ~480 ms an rgb one with its video), which two workers
already fill; and an rgb episode travels to it as 2.1 MiB of raw frames. A shard is encoded where it is recorded
and travels as its finished files (0.15 MiB an rgb episode), so the writers scale with the workers and the driver
only stores shards and merges them (`merge.py`, through `lerobot.datasets.aggregate`).

What stays the same: the merged dataset is the recording one writer makes of the same seeds (frames, indices,
episode metadata, MCAP logs; tested), whatever the executor and the shard size. Shards are journaled (kept whole
in `<out>.journal/shards/`) as they arrive, so a kill loses at most the shards in flight and `--resume` continues
after the last shard stored. A seed whose simulation fails is dropped and more seeds are recorded, as without
shards. Not available with `only_success`: which seeds a shard keeps would then depend on the shard size.
The dataset appears when every shard is in (merging takes seconds), not at commits along the way.
"""

from __future__ import annotations

import io
import os
import shutil
import sys
import tarfile
import tempfile
import time
from collections.abc import Iterator
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from kitbench import faults
from kitbench.engine import RolloutEngine, Work, make_executor
from kitbench.recording.config import RecordConfig
from kitbench.recording.durable import fsync_dir, fsync_new
from kitbench.recording.journal import SHARDS_DIR, EpisodeJournal
from kitbench.recording.run import RecordingRun
from kitbench.recording.stops import StopSignals
from kitbench.recording.summary import Summary

if TYPE_CHECKING:
    from kitbench.metadata import EpisodeInfo

SHARD_PREFIX = "shard-"
# A shard is one session: committed once, at its end (a commit costs a session clone and a finalize).
SHARD_COMMIT_INTERVAL = 1e9


@dataclass
class ShardResult:
    first_seed: int
    seeds: int  # seeds attempted: first_seed .. first_seed + seeds - 1
    stored: int
    successes: int
    physics_errors: int
    frames: int
    data: bytes  # the shard's dataset folder as an uncompressed tar (its parquet and video are compressed already)


def _tar(folder: Path) -> bytes:
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w") as tar:
        tar.add(folder, arcname=".")
    return buffer.getvalue()


class ShardWork(Work):
    """Records the shard (first seed, seed count) on one writer in the worker's process (`record_episodes`)."""

    def __init__(self, config: RecordConfig):
        self.config = config

    def setup(self) -> None:
        """Nothing shared: each shard is a recording of its own (it builds its env, seconds a shard)."""

    def run(self, job: tuple[int, int]) -> ShardResult:
        from kitbench.recording.one_writer import record_episodes

        first, count = job
        with tempfile.TemporaryDirectory(prefix="kitbench-shard-") as scratch:
            shard = self.config.replace(
                seed=first,
                episodes=count,
                out=Path(scratch) / "shard",
                max_attempts=count,  # exactly its seeds: a failed simulation leaves the shard one short
                workers=1,
                executor="local",
                ray_address="auto",
                resume=False,
                overwrite=False,
                shard_episodes=0,
                commit_interval=SHARD_COMMIT_INTERVAL,
            )
            summary = record_episodes(shard, progress=False, signals=False)  # the worker's signals are its pool's
            data = _tar(shard.out) if summary.stored else b""
        return ShardResult(
            first, count, summary.stored, summary.successes, summary.physics_errors, summary.frames, data
        )


def _shard_folder(journal: EpisodeJournal) -> Path:
    return journal.root / SHARDS_DIR


def journaled_shards(journal: EpisodeJournal) -> list[Path]:
    """The whole shards a recording has stored, in seed order (a partial one was in flight)."""
    folder = _shard_folder(journal)
    return sorted(folder.glob(f"{SHARD_PREFIX}*")) if folder.is_dir() else []


def _unpublished(journal: EpisodeJournal, out: Path) -> list[Path]:
    """The journaled shards not yet in the dataset at `out`, in seed order. A run killed after publishing its
    merge but before deleting its journal left shards the dataset holds already: they are deleted, not merged
    twice. A shard damaged on disk (a kill leaves none) is deleted with those after it, which are recorded again."""
    from kitbench.integrity import Damage, check_dataset

    shards = journaled_shards(journal)
    last = max((e.seed for e in _episodes(out)), default=-1) if out.exists() else -1
    kept: list[Path] = []
    for i, shard in enumerate(shards):
        if int(shard.name[len(SHARD_PREFIX) :]) <= last:
            shutil.rmtree(shard)
            continue
        try:
            check_dataset(shard)
        except Damage as exc:
            print(
                f"kitbench record: journaled shard {exc.path}: {exc.problem}: it and the shards after it are "
                "recorded again",
                file=sys.stderr,
            )
            for later in shards[i:]:
                shutil.rmtree(later)
            break
        kept.append(shard)
    return kept


def _store_shard(journal: EpisodeJournal, result: ShardResult) -> Path:
    """Unpack a shard durably under the journal: whole under its final name, or not there at all."""
    folder = _shard_folder(journal)
    folder.mkdir(parents=True, exist_ok=True)
    final = folder / f"{SHARD_PREFIX}{result.first_seed:010d}"
    partial = folder / f".partial-{result.first_seed:010d}"
    shutil.rmtree(partial, ignore_errors=True)
    with tarfile.open(fileobj=io.BytesIO(result.data), mode="r") as tar:
        tar.extractall(partial, filter="data")
    faults.point("shards.extracting")
    fsync_new(partial)
    os.replace(partial, final)
    fsync_dir(folder)
    return final


def _episodes(root: Path) -> list[EpisodeInfo]:
    from kitbench.metadata import read_episodes

    return read_episodes(root)


def record_sharded(config: RecordConfig, progress: bool) -> Summary:
    """`record` with `config.executor.shard_episodes` > 0 (validated by the caller). Workers start before
    anything is written or replaced."""
    from kitbench.recording.dataset import recover

    out = config.out
    journal = EpisodeJournal(out)
    done: list[Path] = []  # recordings to merge: the published dataset (a resumed one), then the shards
    if not config.output.overwrite:
        recover(out)
        done = ([out] if out.exists() else []) + _unpublished(journal, out)
    recording = ShardedRecording(config, journal, done, progress)
    started = time.monotonic()
    with ExitStack() as workers:
        engine = None
        missing = config.episodes - recording.summary.stored
        if missing > 0:
            shards = -(-missing // config.executor.shard_episodes)  # rounded up
            executor = make_executor(config.executor, jobs=shards)
            engine = workers.enter_context(RolloutEngine(executor, ShardWork(config)))
        summary = recording.run(engine)
    return summary.measured(started, out)


class ShardedRecording(RecordingRun):
    """Shards handed out in seed order, each stored in the journal as it arrives, merged into the dataset at the
    end; a stop keeps the stored shards in the journal for --resume."""

    kept = "shard"

    def __init__(self, config: RecordConfig, journal: EpisodeJournal, done: list[Path], progress: bool):
        seeds = [e.seed for root in done for e in _episodes(root)]
        super().__init__(config, Summary(stored=len(seeds)), progress)
        self.journal, self.done = journal, done
        self.last_seed = max(seeds, default=config.demo.seed - 1)
        self.jobs_in_flight = 0
        self.seeds_in_flight = 0

    def _start(self, engine: RolloutEngine | None) -> None:
        from kitbench.recording.dataset import remove_recording

        if self.config.output.overwrite:
            remove_recording(self.config.out)
        self.journal.start(self.config.info())
        if engine is not None:
            self._open_bar(self.config.episodes - self.summary.stored, f"record {self.config.task} (shards)")

    def _record(self, engine: RolloutEngine | None, stops: StopSignals) -> None:
        summary = self.summary
        if engine is not None:
            for (_, size), result in engine.results(self._blocks(), self._needed):
                self.jobs_in_flight -= 1
                self.seeds_in_flight -= size
                summary.attempted += result.seeds
                summary.successes += result.successes
                summary.physics_errors += result.physics_errors
                if result.stored:
                    with stops.storing():
                        self.done.append(_store_shard(self.journal, result))
                        summary.stored += result.stored
                        summary.frames += result.frames
                    if self.bar is not None:
                        self.bar.update(result.stored)
                if summary.should_stop(self.config.episodes, self.limit):
                    break
        with stops.storing():
            _publish(self.done, self.config.out)

    def _recorded(self) -> None:
        faults.point("shards.swapped")
        self.journal.remove()

    def _missing(self) -> int:
        """Seeds still to hand out."""
        summary = self.summary
        return min(self.config.episodes - summary.stored, self.limit - summary.attempted) - self.seeds_in_flight

    def _needed(self) -> int:
        """Jobs that may be in flight: those running, and one more while seeds are missing."""
        return self.jobs_in_flight + (1 if self._missing() > 0 else 0)

    def _blocks(self) -> Iterator[tuple[int, int]]:
        """(first seed, seed count) of each shard, consecutive after the last seed stored."""
        seed = max(self.last_seed + 1, self.config.demo.seed)
        while True:
            size = min(self.config.executor.shard_episodes, self._missing())
            self.jobs_in_flight += 1
            self.seeds_in_flight += size
            yield seed, size
            seed += size


def _publish(done: list[Path], out: Path) -> None:
    """Make `done` (the published dataset, if any, then the shards, in seed order) the dataset at `out`."""
    from kitbench.recording.merge import merge

    if not done or done == [out]:
        return
    if len(done) == 1:  # one shard, nothing published before: it is the dataset
        os.replace(done[0], out)
        return
    staging = out.with_name(out.name + ".merged")
    shutil.rmtree(staging, ignore_errors=True)
    merge(done, staging, finished=False)  # `out`, when extended, has this recording's journal beside it
    faults.point("shards.merged")
    retired = out.with_name(out.name + ".retired")
    if out.exists():
        os.replace(out, retired)
    os.replace(staging, out)
    shutil.rmtree(retired, ignore_errors=True)
