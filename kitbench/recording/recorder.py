"""`kitbench record`: run a policy (the expert by default) over consecutive seeds and write a LeRobot dataset
with one MCAP log per episode in `<out>/mcap/`.

Episodes are produced in seed order whatever the number of worker processes, so a dataset depends only on its
settings. Everything is validated before anything is written.
"""

from __future__ import annotations

import dataclasses
import multiprocessing as mp
import os
import shutil
import tempfile
import time
import tomllib
from collections import deque
from dataclasses import dataclass
from pathlib import Path

from kitbench.errors import KitbenchError
from kitbench.metadata import RECORDING_FILE
from kitbench.registration import task_entry

MCAP_DIR = "mcap"


@dataclass(frozen=True)
class RecordConfig:
    task: str
    episodes: int
    out: Path
    seed: int = 0
    obs_mode: str = "state"
    control_mode: str = "pd_joint_delta_pos"
    policy: str = "expert"
    only_success: bool = False
    workers: int = 1
    resume: bool = False
    overwrite: bool = False
    mcap: bool = True
    repo_id: str | None = None
    # Seconds between commits. Opening a session costs ~1.5 s (lerobot re-reads the episode index), so
    # committing after every episode (0) is strictly durable but slow; a kill loses at most this much work,
    # which --resume regenerates exactly (episodes are deterministic in their seed).
    commit_interval: float = 30.0

    @property
    def dataset_repo_id(self) -> str:
        return self.repo_id or f"kitbench/{self.task}"

    def identity(self) -> dict:
        """The settings a resumed recording must share with the original, including the kitbench version:
        episodes are reproducible from their seed only under the same physics and assets."""
        import kitbench

        settings = ("task", "seed", "obs_mode", "control_mode", "policy", "only_success")
        return {**{k: getattr(self, k) for k in settings}, "kitbench_version": kitbench.__version__}


RECIPE_KEYS = {f.name for f in dataclasses.fields(RecordConfig)}
OBS_MODES_RECORDABLE = ("state", "rgb", "rgbd")


def load_recipe(path: Path, **overrides) -> RecordConfig:
    """A TOML recipe: the same keys as the command line's long options (`[record]` table or top level)."""
    path = Path(path)
    if not path.is_file():
        raise KitbenchError(f"recipe {path} does not exist")
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise KitbenchError(f"recipe {path}: invalid TOML: {exc}") from exc
    data = data.get("record", data)
    unknown = sorted(set(data) - RECIPE_KEYS)
    if unknown:
        raise KitbenchError(
            f"recipe {path}: unknown key(s) {', '.join(unknown)}; valid keys: {', '.join(sorted(RECIPE_KEYS))}"
        )
    for key in ("task", "episodes", "out"):
        if key not in data and key not in overrides:
            raise KitbenchError(f"recipe {path}: missing required key {key!r}")
    data.update({k: v for k, v in overrides.items() if v is not None})
    data["out"] = Path(data["out"])
    return RecordConfig(**data)


def validate(config: RecordConfig) -> None:
    """Every check that can fail before a file is written."""
    task_entry(config.task)
    if config.obs_mode not in OBS_MODES_RECORDABLE:
        raise KitbenchError(
            f"unknown obs_mode {config.obs_mode!r} for recording; valid choices: {', '.join(OBS_MODES_RECORDABLE)}"
        )
    if not isinstance(config.episodes, int) or config.episodes < 1:
        raise KitbenchError(f"episodes must be a positive integer, got {config.episodes!r}")
    if not isinstance(config.workers, int) or config.workers < 1:
        raise KitbenchError(f"workers must be a positive integer, got {config.workers!r}")
    if config.resume and config.overwrite:
        raise KitbenchError("--resume and --overwrite exclude each other")
    out = config.out
    if out.exists() and not (config.resume or config.overwrite):
        raise KitbenchError(f"output folder {out} exists; pass --resume to continue it or --overwrite to replace it")
    if config.resume and out.exists():
        import json

        saved_path = out / RECORDING_FILE
        if not saved_path.is_file():
            raise KitbenchError(f"cannot resume {out}: it is not a kitbench recording ({RECORDING_FILE} missing)")
        saved = json.loads(saved_path.read_text())
        mismatched = {k: (saved.get(k), v) for k, v in config.identity().items() if saved.get(k) != v}
        if mismatched:
            detail = ", ".join(f"{k}: recorded {a!r}, asked {b!r}" for k, (a, b) in mismatched.items())
            raise KitbenchError(f"cannot resume {out} with different settings ({detail})")
    env = make_recording_env(config)  # raises on a bad control mode, robot or task setting
    try:
        from kitbench.policies.registry import make_policy

        policy = make_policy(config.policy)
        if config.policy == "expert":
            from kitbench.policies.expert import check_has_expert

            check_has_expert(env)
        del policy
    finally:
        env.close()


def make_recording_env(config: RecordConfig):
    from kitbench.registration import make_env

    return make_env(config.task, obs_mode=config.obs_mode, control_mode=config.control_mode, reward_mode="dense")


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
        from tqdm import tqdm

        bar = tqdm(total=remaining, desc=f"record {config.task}", unit="ep", dynamic_ncols=True)
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
