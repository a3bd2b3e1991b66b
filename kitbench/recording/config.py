"""What `kitbench record` is asked to do: its settings (`RecordConfig`), recipe files, and every check that can
fail before a file is written (`validate`)."""

from __future__ import annotations

import dataclasses
import tomllib
from dataclasses import dataclass
from pathlib import Path

from kitbench.errors import KitbenchError
from kitbench.metadata import RECORDING_FILE
from kitbench.registration import task_entry


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
