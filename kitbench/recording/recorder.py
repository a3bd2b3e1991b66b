"""`kitbench record`: run a policy (the expert by default) over consecutive seeds and write a LeRobot dataset
with one MCAP log per episode in `<out>/mcap/`.

Episodes are produced in seed order whatever the number of worker processes, so a dataset depends only on its
settings. Everything is validated (`recording.config.validate`) before anything is written.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import shutil
import tempfile
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path

from kitbench.recording.config import RecordConfig, load_recipe, make_recording_env, validate

MCAP_DIR = "mcap"

__all__ = ["MCAP_DIR", "RecordConfig", "Summary", "load_recipe", "make_recording_env", "record", "validate"]


# -- workers ----------------------------------------------------------------------------------------
_WORKER: dict = {}


def _worker_init(config: RecordConfig, mcap_tmp: str | None) -> None:
    from kitbench.policies.registry import make_policy

    _WORKER["env"] = make_recording_env(config)
    _WORKER["policy"] = make_policy(config.policy)
    _WORKER["mcap_tmp"] = mcap_tmp


def _worker_episode(seed: int):
    from kitbench.recording.rollout import run_episode

    mcap_tmp = _WORKER["mcap_tmp"]
    path = Path(mcap_tmp) / f"seed-{seed:08d}.mcap" if mcap_tmp else None
    return run_episode(_WORKER["env"], _WORKER["policy"], seed, path), path


class _InProcess:
    """The worker protocol without processes (workers=1): same code path, same results."""

    def __init__(self, config, mcap_tmp):
        _worker_init(config, mcap_tmp)

    def submit(self, seed):
        result = _worker_episode(seed)
        return lambda: result

    def close(self):
        _WORKER["env"].close()


class _Pool:
    def __init__(self, config, mcap_tmp, workers):
        self._pool = mp.get_context("spawn").Pool(workers, initializer=_worker_init, initargs=(config, mcap_tmp))

    def submit(self, seed):
        return self._pool.apply_async(_worker_episode, (seed,)).get

    def close(self):
        self._pool.terminate()
        self._pool.join()


# -- the recording loop -----------------------------------------------------------------------------
@dataclass
class Summary:
    stored: int = 0
    attempted: int = 0
    successes: int = 0
    failures_dropped: int = 0
    frames: int = 0
    seconds: float = 0.0
    size_bytes: int = 0
    interrupted: bool = False
    signal: int | None = None  # the signal that interrupted the run (SIGINT for Ctrl-C)
    gave_up: bool = False  # stopped at max_attempts before storing every episode
    physics_errors: int = 0  # attempts dropped because the simulation failed (info["physics_error"])

    @property
    def exit_code(self) -> int:
        """The command's exit status: 128 + the signal when interrupted (130 for Ctrl-C), 3 when it gave up at
        --max-attempts, 0 otherwise."""
        if self.interrupted:
            return 128 + (self.signal or 2)
        return 3 if self.gave_up else 0

    def lines(self, out: Path) -> list[str]:
        rate = self.successes / self.attempted if self.attempted else 0.0
        per_min = 60.0 * self.attempted / self.seconds if self.seconds > 0 else 0.0
        lines = [
            f"dataset: {out}",
            (
                f"episodes stored: {self.stored} (attempted {self.attempted}, success rate {rate:.1%}"
                + (f", {self.failures_dropped} failed attempts not stored)" if self.failures_dropped else ")")
            ),
            (
                f"frames: {self.frames}   speed: {per_min:.1f} episodes/min, "
                f"{self.frames / max(self.seconds, 1e-9):.0f} frames/s"
            ),
            f"size on disk: {self.size_bytes / 2**20:.1f} MiB",
        ]
        if self.interrupted:
            lines.insert(0, "interrupted: every completed episode was committed; continue with --resume")
        return lines


def _folder_size(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file()) if path.exists() else 0


def record(config: RecordConfig, progress: bool = True) -> Summary:
    from kitbench.recording.dataset import DatasetWriter, recover
    from kitbench.recording.features import dataset_features

    validate(config)
    out = config.out
    if config.overwrite:
        recover(out)
        if out.exists():
            shutil.rmtree(out)
    recover(out)
    committed = DatasetWriter.committed_episodes(out) if out.exists() else []
    next_seed = (max(e["seed"] for e in committed) + 1) if committed else config.seed
    env = make_recording_env(config)
    env.reset(seed=config.seed)
    features = dataset_features(env)
    fps = env.unwrapped.sim_config.control_freq
    robot_uid = env.unwrapped.robot_uid
    env.close()
    recording = {**config.identity(), "repo_id": config.dataset_repo_id, "fps": fps}
    writer = DatasetWriter(out, config.dataset_repo_id, fps, features, robot_uid, recording)
    summary = Summary(stored=len(committed))
    remaining = config.episodes - len(committed)
    out.parent.mkdir(parents=True, exist_ok=True)
    mcap_tmp = tempfile.mkdtemp(prefix=f".{out.name}.mcap-", dir=out.parent) if config.mcap else None
    runner = _InProcess(config, mcap_tmp) if config.workers == 1 else _Pool(config, mcap_tmp, config.workers)
    bar = None
    if progress and remaining > 0:
        from kitbench.progress import progress as progress_bar

        bar = progress_bar(remaining, f"record {config.task}")
    start = time.monotonic()
    pending: deque = deque()
    seed = next_seed
    try:
        while summary.stored < config.episodes:
            while len(pending) < 2 * config.workers:
                pending.append((seed, runner.submit(seed)))
                seed += 1
            _, get = pending.popleft()
            episode, mcap_path = get()
            summary.attempted += 1
            summary.successes += int(episode.success)
            if config.only_success and not episode.success:
                summary.failures_dropped += 1
                if mcap_path is not None and mcap_path.exists():
                    mcap_path.unlink()
            else:
                index = writer.add_episode(episode, {})
                if mcap_path is not None:
                    target = writer.session_root / MCAP_DIR / f"episode_{index:06d}.mcap"
                    target.parent.mkdir(parents=True, exist_ok=True)
                    os.replace(mcap_path, target)
                summary.stored += 1
                summary.frames += episode.length
                if bar is not None:
                    bar.update(1)
                if summary.stored == config.episodes or writer.session_age() >= config.commit_interval:
                    writer.commit()
            if bar is not None:
                bar.set_postfix(success=f"{summary.successes / summary.attempted:.0%}", tried=summary.attempted)
        writer.commit()
    except KeyboardInterrupt:
        writer.commit()
        summary.interrupted = True
    except BaseException:
        writer.abandon()
        raise
    finally:
        runner.close()
        if bar is not None:
            bar.close()
        if mcap_tmp:
            shutil.rmtree(mcap_tmp, ignore_errors=True)
    summary.seconds = time.monotonic() - start
    summary.size_bytes = _folder_size(out)
    return summary
