"""What `kitbench record` (and `kitbench convert`) is asked to do: `RecordConfig`, each setting declared once
(`kitbench.config`), recipe files, and every check that can fail before a file is written (`validate`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from kitbench.config import declare
from kitbench.config.checks import is_int, non_negative_int, one_of, optional, positive_int, seconds, seed
from kitbench.config.declare import setting
from kitbench.config.files import read_settings
from kitbench.engine.config import ExecutorConfig
from kitbench.env_settings import EnvSettings
from kitbench.envs.modes import camera_textures
from kitbench.envs.pointcloud import DEFAULT_POINTS
from kitbench.errors import KitbenchError, one_line
from kitbench.metadata import ACTION_CONVENTION, RECORDING_FILE, RecordingInfo, expert_options, teleop_options
from kitbench.policies.lerobot_policy import parse_option
from kitbench.recording.features import RGB_STORAGES
from kitbench.recording.layout import RETIRED_SUFFIX, SHARDS_DIR, beside, journal_root, last_commit
from kitbench.registration import task_entry
from kitbench.rollout import SettleSettings
from kitbench.teleop.checks import check_record_settings

LABELS = ("expert",)


def _noise(name: str, value: object) -> None:
    if not (isinstance(value, int | float) and not isinstance(value, bool) and 0 <= value < math.inf):
        raise KitbenchError(f"{name} must be a finite number >= 0 (0: no noise), got {value!r}")


def _phases(name: str, value: object) -> None:
    if value is not None and not (isinstance(value, tuple) and value and all(isinstance(p, str) for p in value)):
        raise KitbenchError(f"{name} must be a non-empty list of phase names, got {value!r}")


def _repo_id(name: str, value: object) -> None:
    """Refuse a repo id the Hugging Face Hub would refuse (lerobot writes it into the dataset and pushes under it)."""
    if value is None:
        return
    from huggingface_hub.errors import HFValidationError

    # public, but re-exported through a computed __all__ that mypy cannot read
    from huggingface_hub.utils import validate_repo_id  # type: ignore[attr-defined]

    try:
        validate_repo_id(str(value))
    except HFValidationError as exc:
        # the hub's message ends by quoting the id and may advise on an argument the command line does not have
        reason = one_line(exc, typed=False).replace(f": '{value}'", "")
        reason = reason.replace(" Use `repo_type` argument if needed.", "")
        raise KitbenchError(f"invalid repo_id {value!r}: {reason[:1].lower()}{reason[1:]}") from None


def check_repo_id(repo_id: object) -> None:
    _repo_id("repo_id", repo_id)


@dataclass
class PolicySettings:
    # Who acts: expert, random, zero, replay:<dataset>[:episode], lerobot:<checkpoint> (its rollouts; with
    # --only-success its successes) or teleop:<device> (a person with one of LeRobot's teleoperators).
    policy: str = setting("expert")
    # Set a field of the expert's planner config (close_steps=8), a lerobot checkpoint's config, or a
    # teleoperator's (port=/dev/ttyACM0, id=my_leader), for this run (repeatable).
    policy_options: tuple[tuple[str, object], ...] = setting(
        (), flag="--policy-option", repeat=True, parse=parse_option, metavar="KEY=VALUE"
    )
    # expert: store as each frame's action what the task's expert commands from the state the policy reached
    # (DAgger); executed_action keeps the policy's own.
    label: str | None = setting(None, check=one_of(LABELS, optional=True))


@dataclass
class DemoSettings(SettleSettings):
    # Episodes to store.
    episodes: int | None = setting(None, check=optional(positive_int))
    # First seed, >= 0; episode k uses seed + k.
    seed: int = setting(0, check=seed)
    # Store successful episodes only.
    only_success: bool = setting(False)
    # Episodes to attempt, stored or not, before giving up with exit status 3 (default 10 x --episodes).
    max_attempts: int | None = setting(None)
    # Execute actions with seeded Gaussian noise, in units of the control mode's noise unit (0.02 rad a joint);
    # the dataset keeps the clean actions as labels (0: none).
    action_noise: float = setting(0.0, check=_noise)
    # The expert phases the action noise runs in, comma-separated, e.g. transport,align (default: all phases).
    noise_phases: tuple[str, ...] | None = setting(None, check=_phases)


@dataclass
class OutputSettings:
    # The dataset folder (the LeRobot root; MCAP logs go to <out>/mcap).
    out: Path | None = setting(None)
    # The dataset's repo id, [namespace/]name as on the Hub (default kitbench/<task>).
    repo_id: str | None = setting(None, check=_repo_id)
    # How rgb frames are stored: video (h264, lossy, LeRobot's default) or images (PNG, lossless, ~4x the bytes).
    rgb_storage: str = setting("video", check=one_of(RGB_STORAGES))
    # Write an MCAP log per episode.
    mcap: bool = setting(True)
    # Continue an interrupted recording in --out.
    resume: bool = setting(False)
    # Replace an existing --out.
    overwrite: bool = setting(False)
    # Seconds between commits (0 commits after every episode). Opening a session costs ~1.5 s (lerobot re-reads
    # the episode index), so commits are periodic; every finished episode is journaled first (recording/journal.py).
    commit_interval: float = setting(30.0, check=seconds)


@dataclass
class RecordingExecutor(ExecutorConfig):
    # Episodes per shard: each worker writes whole shards, merged at the end, so writing scales with the workers
    # (0: one writer; docs/scale-out.md).
    shard_episodes: int = setting(0, check=non_negative_int)


@dataclass
class RecordConfig:
    """`kitbench record`: which env (`env`), who acts (`policy`), which episodes (`demo`), where they run
    (`executor`) and where they go (`output`). A conversion names its `source` recording."""

    env: EnvSettings = field(default_factory=EnvSettings)
    policy: PolicySettings = field(default_factory=PolicySettings)
    demo: DemoSettings = field(default_factory=DemoSettings)
    executor: RecordingExecutor = field(default_factory=RecordingExecutor)
    output: OutputSettings = field(default_factory=OutputSettings)
    # A kitbench recording to re-simulate (`kitbench convert`): its seeds, in its order, replayed with the actions
    # its robot executed; None: the policy acts on consecutive seeds from `seed`.
    source: Path | None = setting(None, cli=False)

    @classmethod
    def of(cls, task: str | None = None, episodes: int | None = None, out: Path | str | None = None, **settings: Any):
        """A config from flat settings (`task, episodes, out, seed=..., obs_mode=...`), as a recipe or the flags
        give them."""
        named = {"task": task, "episodes": episodes, "out": out}
        config = declare.build(cls, {**{k: v for k, v in named.items() if v is not None}, **settings})
        if config.output.out is not None:
            config.output.out = Path(config.output.out)
        if isinstance(config.demo.noise_phases, list):  # as a recipe (TOML) writes it
            config.demo.noise_phases = tuple(config.demo.noise_phases)
        return config

    def replace(self, **settings: Any) -> RecordConfig:
        return declare.replace(self, **settings)

    @property
    def out(self) -> Path:
        assert self.output.out is not None, "validated: a recording has an output folder"
        return self.output.out

    @property
    def task(self) -> str:
        assert self.env.task is not None, "validated: a recording has a task"
        return self.env.task

    @property
    def episodes(self) -> int:
        assert self.demo.episodes is not None, "validated: a recording has an episode count"
        return self.demo.episodes

    @property
    def dataset_repo_id(self) -> str:
        return self.output.repo_id or f"kitbench/{self.task}"

    def info(self, **more: Any) -> RecordingInfo:
        """The recording's settings as its dataset stores them."""
        import kitbench

        return RecordingInfo(
            task=self.task,
            seed=self.demo.seed,
            obs_mode=self.env.obs_mode,
            control_mode=self.env.control_mode,
            policy=self.policy.policy,
            only_success=self.demo.only_success,
            action_noise=self.demo.action_noise,
            noise_phases=None if self.demo.noise_phases is None else list(self.demo.noise_phases),
            settle_steps=self.demo.settle_steps,
            reward_mode=self.env.reward_mode,
            robot=self.env.robot,
            pointcloud_points=self.env.pointcloud_points if self.env.obs_mode == "pointcloud" else None,
            camera_size=self.env.camera_size if self.env.obs_mode != "state" else None,
            camera_view=self.env.camera_view if self.env.obs_mode != "state" else None,
            rgb_storage=self.output.rgb_storage,
            label=self.policy.label,
            expert_options=expert_options(self.policy.policy, self.policy.policy_options),
            teleop_options=teleop_options(self.policy.policy, self.policy.policy_options),
            source=None if self.source is None else str(self.source),
            kitbench_version=kitbench.__version__,
            action_convention=ACTION_CONVENTION,
            repo_id=self.dataset_repo_id,
            **more,
        )


RECIPE_KEYS = tuple(name for name, leaf in declare.leaves(RecordConfig).items() if name != "source")
RECIPE_TABLE = "record"
REQUIRED = ("task", "episodes", "out")


def load_recipe(path: Path, **overrides: Any) -> RecordConfig:
    """A TOML recipe: the same keys as the command line's long options (`[record]` table or top level); non-None
    `overrides` win."""
    path = Path(path)
    data = read_settings(path, "recipe", RECIPE_TABLE, RECIPE_KEYS)
    if "policy_options" in data:
        data["policy_options"] = _recipe_options(data["policy_options"], path)
        asked, policy = overrides.get("policy_options"), data.get("policy", PolicySettings.policy)
        if asked and overrides.get("policy") in (None, policy):  # the same policy's options: added key by key
            overrides = {**overrides, "policy_options": tuple({**dict(data["policy_options"]), **dict(asked)}.items())}
    for key in REQUIRED:
        if key not in data and overrides.get(key) is None:
            raise KitbenchError(f"recipe {path}: missing required key {key!r}")
    return RecordConfig.of(**declare.resolve(("recipe", data), ("command line", overrides)).values)


def _recipe_options(value: Any, path: Path) -> tuple[tuple[str, object], ...]:
    """A recipe's `policy_options`: a table (`{close_steps = 8}`) or a list of `"KEY=VALUE"` as on the command line."""
    if isinstance(value, dict):
        return tuple(value.items())
    if isinstance(value, list) and all(isinstance(v, str) for v in value):
        return tuple(parse_option(v) for v in value)
    raise KitbenchError(
        f'recipe {path}: policy_options is {value!r}; give a table ({{close_steps = 8}}) or a list of "KEY=VALUE"'
    )


def validate(config: RecordConfig) -> None:
    """Every check that can fail before a file is written."""
    missing = [f"--{k}" for k in REQUIRED if declare.get(config, k) is None]
    if missing:
        raise KitbenchError(f"missing {', '.join(missing)} (or give a recipe file)")
    task_entry(config.task)
    declare.validate(config)
    config.env.check_robot()
    config.env.check_camera_view()
    demo = config.demo
    if config.policy.label is not None and config.policy.policy == config.policy.label:
        raise KitbenchError(
            f"label {config.policy.label!r} labels policy {config.policy.policy!r} with itself; drop --label"
        )
    _check_noise_phases(config)
    if demo.max_attempts is not None and not (is_int(demo.max_attempts) and demo.max_attempts >= config.episodes):
        raise KitbenchError(
            f"max_attempts must be a positive integer >= episodes ({config.episodes}), got {demo.max_attempts!r}"
        )
    out = config.output
    if out.resume and out.overwrite:
        raise KitbenchError("--resume and --overwrite exclude each other")
    config.executor.validate()
    executor = config.executor
    check_record_settings(
        config.policy.policy, executor.workers, executor.executor, executor.shard_episodes, demo.action_noise
    )
    if config.executor.shard_episodes and demo.only_success:
        raise KitbenchError(
            "shard_episodes and only_success exclude each other: which seeds a shard keeps would depend on the "
            "shard size; record all episodes, or record without shards"
        )
    _check_output(config)
    from kitbench.doctor import require_renderer

    require_renderer(config.env.obs_mode)
    if config.source is not None:
        _check_source(config)
        return
    env = make_recording_env(config)  # raises on a bad control mode, robot or task setting
    try:
        from kitbench.policies.registry import make_policy

        policy = make_policy(config.policy.policy, options=dict(config.policy.policy_options))
        if config.policy.policy == "expert" or config.policy.label == "expert":
            from kitbench.policies.expert import check_has_expert

            check_has_expert(env, expert_options(config.policy.policy, config.policy.policy_options))
        _check_policy_fits(config, policy, env)
        del policy
    finally:
        env.close()


def _check_source(config: RecordConfig) -> None:
    """A conversion's source is a kitbench recording of this task, replayed without noise of its own."""
    source = RecordingInfo.require(config.source)  # type: ignore[arg-type]  # only called with one
    if source.task != config.task:
        raise KitbenchError(f"{config.source} records {source.task}, not {config.task}")
    if config.demo.action_noise or config.policy.label is not None:
        raise KitbenchError("a conversion replays its source's actions: no action_noise or label of its own")
    if config.executor.shard_episodes:
        raise KitbenchError("a conversion runs its source's seeds on one writer: drop shard_episodes")
    env = make_recording_env(config)  # raises on a bad obs mode, control mode or robot
    env.close()


def _check_policy_fits(config: RecordConfig, policy, env) -> None:
    """A trained policy records in the modes and on the robot it was trained for (`requirements()`), asked for
    explicitly: a dataset's settings are the command's, never silently the checkpoint's. Then its own check on
    the env (inputs and action size)."""
    from kitbench.policies.base import requirements_of

    asked = {"control_mode": config.env.control_mode, "robot": config.env.robot_uid, "obs_mode": config.env.obs_mode}
    flags = {"control_mode": "--control-mode", "robot": "--robot", "obs_mode": "--obs-mode"}
    for key, value in requirements_of(policy).items():
        if key in asked and value != asked[key]:
            if key == "obs_mode" and camera_textures(value) <= camera_textures(config.env.obs_mode):
                continue  # the recording asks for more than the policy reads: it gets what it reads
            raise KitbenchError(
                f"policy {config.policy.policy} needs {key} {value} (recording asks for {asked[key]}); record with "
                f"{flags[key]} {value}"
            )
    from kitbench.policies.base import check_fits

    check_fits(policy, env)


def _check_noise_phases(config: RecordConfig) -> None:
    """`noise_phases` names phases of the task's expert, for a recording with noise, run by that expert."""
    phases = config.demo.noise_phases
    if phases is None:
        return
    if not config.demo.action_noise:
        raise KitbenchError("noise_phases needs action_noise > 0: it names the expert phases the noise runs in")
    if config.policy.policy != "expert":
        raise KitbenchError(f"noise_phases names phases of the expert; policy {config.policy.policy!r} has none")
    expert = task_entry(config.task).env_class.expert_class(config.env.robot)
    valid = getattr(expert, "phases", ())
    if not valid:
        raise KitbenchError(f"noise_phases: the {config.task} expert declares no phases (`PhasePlanner.phases`)")
    for phase in phases:
        if phase not in valid:
            raise KitbenchError(
                f"unknown noise phase {phase!r} for the {config.task} expert; valid choices: {', '.join(valid)}"
            )


def _leftovers(out: Path) -> list[Path]:
    """What a recording at `out` leaves besides the dataset folder: the folders of a commit a kill interrupted
    (restored by the recorder) and the journal of episodes not yet committed (a kill before the first commit
    leaves only that)."""
    return [p for p in (beside(out, RETIRED_SUFFIX), journal_root(out)) if p.is_dir()]


def _saved_settings(out: Path) -> list[RecordingInfo]:
    """The settings each part of an interrupted recording at `out` was made with."""
    from kitbench.recording.journal import EpisodeJournal

    folder = last_commit(out)  # what the recorder will restore; an unfinished session is never read
    if folder is not None:
        from kitbench.integrity import check_dataset

        check_dataset(folder)
    committed = RecordingInfo.read(folder) if folder is not None else None
    if committed is not None:
        committed.require_current(out)
    return [info for info in (committed, EpisodeJournal(out).settings()) if info is not None]


def _check_output(config: RecordConfig) -> None:
    """The output folder fits what was asked: new, or an unfinished recording to --resume, or one to --overwrite."""
    out = config.out
    blocker = next((p for p in (out, *out.parents) if p.exists() or p.is_symlink()), None)
    if blocker is not None and not blocker.is_dir():
        where = "" if blocker == out else f" ({blocker} is a file)"
        raise KitbenchError(f"output {out} is not a folder{where}; give --out a folder path")
    leftovers = _leftovers(out)
    resume, overwrite = config.output.resume, config.output.overwrite
    if not resume and not overwrite:
        if out.exists():
            raise KitbenchError(
                f"output folder {out} exists; pass --resume to continue it or --overwrite to replace it"
            )
        if leftovers:
            raise KitbenchError(
                f"an unfinished recording of {out} exists ({leftovers[0]}); pass --resume to continue it or "
                "--overwrite to replace it"
            )
    if not resume:
        return
    if (journal_root(out) / SHARDS_DIR).is_dir() and not config.executor.shard_episodes:
        raise KitbenchError(f"{out} is an unfinished sharded recording; resume it with --shard-episodes N")
    if not out.exists() and not leftovers:
        raise KitbenchError(f"nothing to resume at {out} (drop --resume to start one)")
    if out.exists() and RecordingInfo.read(out) is None:
        raise KitbenchError(f"cannot resume {out}: it is not a kitbench recording ({RECORDING_FILE} missing)")
    asked = config.info()
    for saved in _saved_settings(out):
        mismatched = saved.differences(asked)
        if mismatched:
            detail = ", ".join(f"{k}: recorded {a!r}, asked {b!r}" for k, (a, b) in mismatched.items())
            raise KitbenchError(f"cannot resume {out} with different settings ({detail})")


def make_recording_env(config: RecordConfig, render_mode: str | None = None, step_limit: bool = True):
    """The env `config` records in; `render_mode` "rgb_array" for a person's live view of the scene (visual shapes
    only: the same physics, the same data); `step_limit` False: without the task's step limit (a person ends the
    episode)."""
    from kitbench.registration import NO_STEP_LIMIT, make_env

    env = config.env
    return make_env(
        config.task,
        max_episode_steps=None if step_limit else NO_STEP_LIMIT,
        obs_mode=env.obs_mode,
        control_mode=env.control_mode,
        reward_mode=env.reward_mode,
        robot_uids=env.robot,
        sensor_configs=env.sensor_configs,
        render_mode=render_mode,
    )


__all__ = ["DEFAULT_POINTS", "LABELS", "RecordConfig", "load_recipe", "make_recording_env", "validate"]
