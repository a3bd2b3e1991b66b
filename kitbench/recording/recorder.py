"""`kitbench record`: run a policy (the expert by default) over consecutive seeds and write a LeRobot dataset
with one MCAP log per episode in `<out>/mcap/`.

Episodes run on the rollout engine (`kitbench.engine`: this process, a local process pool, or Ray actors) and
reach the one writer here in seed order, so a dataset depends only on its settings, not on where it was recorded.
Everything is validated (`recording.config.validate`) before anything is written.
"""

from __future__ import annotations

import itertools
import os
import signal
import sys
import time
from contextlib import ExitStack
from pathlib import Path

from kitbench.engine import RolloutEngine, make_executor
from kitbench.recording.config import RecordConfig, load_recipe, make_recording_env, validate
from kitbench.recording.journal import EpisodeJournal
from kitbench.recording.stops import Stopped, StopSignals
from kitbench.recording.summary import Summary, attempt_limit, folder_size
from kitbench.recording.work import RecordWork

MCAP_DIR = "mcap"

__all__ = ["MCAP_DIR", "RecordConfig", "Summary", "load_recipe", "make_recording_env", "record", "validate"]


# -- the recording loop -----------------------------------------------------------------------------
def _say(message: str) -> None:
    print(f"kitbench record: {message}", file=sys.stderr, flush=True)


def publish_episode(writer, episode, mcap_path: Path | None) -> None:
    """Add a journaled episode to the open session, its MCAP log linked in (the journal keeps its copy until
    the commit publishes the session)."""
    index = writer.add_episode(episode, {})
    if mcap_path is not None:
        target = writer.session_root / MCAP_DIR / f"episode_{index:06d}.mcap"
        target.parent.mkdir(parents=True, exist_ok=True)
        os.link(mcap_path, target)


def commit_session(writer, journal: EpisodeJournal, published: list[int]) -> None:
    """Publish the open session and forget its journaled episodes."""
    writer.commit()
    journal.discard(published)
    published.clear()


def open_writer(config: RecordConfig):
    """The dataset writer of `config`'s recording and the settings it stores (features and fps read off the env:
    the one place they are defined)."""
    from kitbench.recording.dataset import DatasetWriter
    from kitbench.recording.features import dataset_features

    env = make_recording_env(config)
    try:
        env.reset(seed=config.seed)
        features = dataset_features(env, config.pointcloud_points, config.rgb_storage)
        fps = env.unwrapped.sim_config.control_freq
        robot_uid = env.unwrapped.robot_uid
    finally:
        env.close()
    recording = {**config.identity(), "repo_id": config.dataset_repo_id, "fps": fps}
    return DatasetWriter(config.out, config.dataset_repo_id, fps, features, robot_uid, recording), recording


def record(config: RecordConfig, progress: bool = True, signals: bool = True) -> Summary:
    """Record `config.episodes` episodes (continuing a recording with `resume`); see the module docstring.
    `signals`: Ctrl-C, SIGTERM and SIGHUP stop the recording cleanly (off for a shard recorded inside a worker)."""
    from kitbench.recording.dataset import DatasetWriter, recover, remove_recording

    validate(config)
    if config.shard_episodes:
        from kitbench.recording.shards import record_sharded

        return record_sharded(config, progress, record)  # each shard is recorded by this function
    out = config.out
    journal = EpisodeJournal(out)
    committed: list[dict] = []
    if not config.overwrite:
        recover(out)
        committed = DatasetWriter.committed_episodes(out) if out.exists() else []
        done_seeds = {e["seed"] for e in committed}
        journal.discard([s for s in journal.seeds() if s in done_seeds])  # published just before a kill
    # Workers start before anything is written or replaced: a run whose workers cannot start (a Ray cluster short
    # of CPUs) leaves everything as it was.
    workers = ExitStack()  # the rollout engine's workers, stopped however the recording ends
    engine = None
    started = time.monotonic()  # the speed printed counts the workers' start-up, as a user waits for it
    to_record = config.episodes - len(committed) - (len(journal.seeds()) if not config.overwrite else 0)
    if to_record > 0:
        executor = make_executor(config.executor_config, jobs=to_record)
        engine = workers.enter_context(RolloutEngine(executor, RecordWork(config)))
    try:
        if config.overwrite:
            remove_recording(out)
        return _record(config, journal, committed, engine, progress, started, signals)
    finally:
        workers.close()


def _seeds(config: RecordConfig, done: set[int], next_seed: int):
    """The seeds still to run: consecutive from `next_seed`, or a conversion's source seeds not yet stored."""
    if config.source is None:
        return itertools.count(next_seed)
    from kitbench.recording.source import SourceRecording

    return iter([s for s in SourceRecording(config.source).seeds if s not in done])


def _record(
    config: RecordConfig,
    journal: EpisodeJournal,
    committed: list[dict],
    engine: RolloutEngine | None,
    progress: bool,
    start: float,
    signals: bool,
) -> Summary:

    out = config.out
    done_seeds = {e["seed"] for e in committed}
    writer, recording = open_writer(config)
    out.parent.mkdir(parents=True, exist_ok=True)
    journal.start(recording)
    summary = Summary(stored=len(committed))
    published: list[int] = []  # seeds in the open session, journaled until it is committed
    bar = None
    try:
        with StopSignals(enabled=signals) as stops:
            # episodes a killed run had finished but not committed: publish them first, in seed order
            replayed: list[int] = []
            for seed in journal.seeds():
                if summary.stored >= config.episodes:
                    break
                episode, mcap_path = journal.load(seed)
                with stops.storing():
                    publish_episode(writer, episode, mcap_path)
                    published.append(seed)
                    replayed.append(seed)
                    summary.stored += 1
            if published:
                # publish them now: a run killed again before its first commit would otherwise replay them all
                # again, and kills coming faster than the replay would stall the recording
                with stops.storing():
                    commit_session(writer, journal, published)
            last = max([*done_seeds, *replayed], default=config.seed - 1)
            next_seed = max(last + 1, config.seed)
            remaining = config.episodes - summary.stored
            limit = attempt_limit(config)
            if remaining > 0 and engine is not None:
                if progress:
                    from kitbench.progress import progress as progress_bar

                    bar = progress_bar(remaining, f"record {config.task}")

                # in flight: never more episodes than are still needed or may still be attempted
                def needed() -> int:
                    return min(config.episodes - summary.stored, limit - summary.attempted)

                seeds = _seeds(config, {*done_seeds, *replayed}, next_seed)
                for _, (episode, mcap) in engine.results(seeds, needed):
                    summary.attempted += 1
                    summary.successes += int(episode.success)
                    if episode.physics_error is not None:
                        summary.physics_errors += 1
                        _say(f"seed {episode.seed}: not stored, the simulation failed: {episode.physics_error}")
                    elif episode.rejected is not None:
                        summary.rejected += 1
                        _say(f"seed {episode.seed}: not stored, {episode.rejected}")
                    keep = episode.physics_error is None and episode.rejected is None
                    if keep and config.only_success and not episode.success:
                        summary.failures_dropped += 1
                        keep = False
                    if keep:
                        with stops.storing():
                            mcap_path = journal.add(episode, mcap)
                            publish_episode(writer, episode, mcap_path)
                            published.append(episode.seed)
                            summary.stored += 1
                            summary.frames += episode.length
                        if bar is not None:
                            bar.update(1)
                        if writer.session_age() >= config.commit_interval:
                            with stops.storing():  # a commit interrupted half-way would leave a session to discard
                                commit_session(writer, journal, published)
                    if bar is not None:
                        bar.set_postfix(success=f"{summary.successes / summary.attempted:.0%}", tried=summary.attempted)
                    if summary.should_stop(config.episodes, limit):
                        break
            with stops.storing():
                commit_session(writer, journal, published)
    except KeyboardInterrupt as exc:
        commit_session(writer, journal, published)
        summary.interrupted = True
        summary.signal = exc.signum if isinstance(exc, Stopped) else signal.SIGINT
    except BaseException:
        writer.abandon()  # the journal keeps every finished episode for --resume
        raise
    finally:
        if bar is not None:
            bar.close()
    if summary.stored >= config.episodes or (config.source is not None and not summary.interrupted):
        journal.remove()  # a conversion is done when every source seed was tried, stored or not
    summary.seconds = time.monotonic() - start
    summary.size_bytes = folder_size(out)
    return summary
