"""What `kitbench record` is asked to do: its settings (`RecordConfig`), recipe files, and every check that can
fail before a file is written (`validate`)."""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path

from kitbench.engine.config import ExecutorConfig
from kitbench.envs.modes import IMAGE_OBS_MODES, POINTCLOUD, REWARD_MODES, camera_textures
from kitbench.envs.pointcloud import DEFAULT_POINTS
from kitbench.errors import KitbenchError
from kitbench.metadata import RECORDING_FILE
from kitbench.recording.features import RGB_STORAGES
from kitbench.recording.noise import check_noise_scale
from kitbench.registration import canonical_task, task_entry
from kitbench.settings import check_seed, read_settings


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
    # Seconds between commits (publishing the episodes stored since the last one as a loadable LeRobot dataset).
    # Opening a session costs ~1.5 s (lerobot re-reads the episode index), so commits are periodic; durability does
    # not depend on them: every finished episode is journaled first (recording/journal.py).
    commit_interval: float = 30.0
    # Episodes attempted (stored or not) before the recording gives up and exits 3; None means 10 x episodes.
    # Only --only-success with a policy that rarely succeeds gets near it, and then it bounds the run.
    max_attempts: int | None = None
    # Demonstrations for learning (recording/rollout.py): executed actions get seeded noise of this many units of
    # the control mode (recording/noise.py; labels stay clean), and episodes run this many steps past success.
    action_noise: float = 0.0
    settle_steps: int = 0
    # The expert's phases (`PhasePlanner.phases`) the noise runs in; None: all of them, until the first success.
    # AssemblingKits' pockets leave 0.69-2 mm a side: at 0.5 noise through every phase the expert kept 24% of
    # its seeds, confined to the phases before the insertion 95% (800 of 840), each demo then re-aiming over the
    # slot from a median 5.7 mm off (docs/learnability.md).
    noise_phases: tuple[str, ...] | None = None
    # What `next.reward` holds (kitbench.envs.modes.REWARD_MODES); stored with the recording's settings.
    reward_mode: str = "dense"
    # The robot (`robot_uids`); None: the task's default (LiftPegUpright: panda). Stored with the settings.
    robot: str | None = None
    # Where episodes run (kitbench.engine.ExecutorConfig): this machine (`workers` processes) or a Ray cluster.
    # Not part of the identity: a dataset is the same whichever ran it, so a resume may change them.
    executor: str = "local"
    ray_address: str = "auto"
    # Episodes per shard (recording/shards.py): each worker records whole shards into datasets of its own, merged
    # at the end, so writing scales with the workers; 0: every episode goes to the one writer here. Not part of
    # the identity either: the merged dataset is the one a single writer makes.
    shard_episodes: int = 0
    # Points stored per frame by obs_mode pointcloud (`observation.pointcloud.*`), sampled from the env's fused
    # cloud with the episode's seed (kitbench.envs.pointcloud).
    pointcloud_points: int = DEFAULT_POINTS
    # How rgb frames are stored (kitbench.recording.features.RGB_STORAGES): h264 video or lossless PNG images.
    rgb_storage: str = "video"
    # Who labels each frame's `action`: None, the policy that acts; "expert", the task's expert, asked at every
    # state the policy reaches (DAgger), while `executed_action` keeps what the policy did.
    label: str | None = None
    # A kitbench recording to re-simulate (`kitbench convert`): its seeds, in its order, replayed with the actions its
    # robot executed (kitbench.recording.convert); None: the policy acts on consecutive seeds from `seed`.
    source: Path | None = None

    def __post_init__(self):
        # stored by its short name (a gym id `kitbench/<task>` is accepted), so the dataset's settings and a
        # --resume comparison do not depend on the spelling
        object.__setattr__(self, "task", canonical_task(self.task))
        if isinstance(self.noise_phases, list):  # as a recipe (TOML) writes it; checked by `validate`
            object.__setattr__(self, "noise_phases", tuple(self.noise_phases))

    @property
    def executor_config(self) -> ExecutorConfig:
        return ExecutorConfig(self.executor, self.workers, self.ray_address)

    @property
    def dataset_repo_id(self) -> str:
        return self.repo_id or f"kitbench/{self.task}"

    def identity(self) -> dict:
        """The settings a resumed recording must share with the original, including the kitbench version:
        episodes are reproducible from their seed only under the same physics and assets."""
        import kitbench

        settings = (
            "task",
            "seed",
            "obs_mode",
            "control_mode",
            "policy",
            "only_success",
            "action_noise",
            # None (noise through every phase) also reads back from recordings made before the option existed
            "noise_phases",
            "settle_steps",
            "reward_mode",
            # None: the task's default robot; a recording made before robots could be chosen has no `robot`
            # setting, which reads as None too, so it resumes under the default and refuses another robot
            "robot",
        )
        identity = {k: getattr(self, k) for k in settings}
        if self.obs_mode == POINTCLOUD:  # recordings of other modes read back without it, as before it existed
            identity["pointcloud_points"] = self.pointcloud_points
        if self.obs_mode != "state":  # recordings made before the option stored video (RECORDED_BEFORE)
            identity["rgb_storage"] = self.rgb_storage
        if self.label is not None:  # likewise: a recording without labels reads back None
            identity["label"] = self.label
        if self.source is not None:
            identity["source"] = str(self.source)
        if self.noise_phases is not None:  # a list, as the JSON it is saved in reads back
            identity["noise_phases"] = list(self.noise_phases)
        return {**identity, "kitbench_version": kitbench.__version__}


# What a setting missing from an older recording's saved settings meant when it was recorded.
RECORDED_BEFORE = {"rgb_storage": "video"}
RECIPE_KEYS = {f.name for f in dataclasses.fields(RecordConfig)}
RECIPE_TABLE = "record"
OBS_MODES_RECORDABLE = ("state", *IMAGE_OBS_MODES)


def load_recipe(path: Path, **overrides) -> RecordConfig:
    """A TOML recipe: the same keys as the command line's long options (`[record]` table or top level)."""
    path = Path(path)
    data = read_settings(path, "recipe", RECIPE_TABLE, RECIPE_KEYS)
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
    if not _is_count(config.episodes):
        raise KitbenchError(f"episodes must be a positive integer, got {config.episodes!r}")
    if config.reward_mode not in REWARD_MODES:
        raise KitbenchError(f"unknown reward_mode {config.reward_mode!r}; valid choices: {', '.join(REWARD_MODES)}")
    check_seed(config.seed)
    _check_label(config)
    if not _is_count(config.pointcloud_points):
        raise KitbenchError(f"pointcloud_points must be a positive integer, got {config.pointcloud_points!r}")
    if config.rgb_storage not in RGB_STORAGES:
        raise KitbenchError(f"unknown rgb_storage {config.rgb_storage!r}; valid choices: {', '.join(RGB_STORAGES)}")
    check_noise_scale(config.action_noise)
    _check_noise_phases(config)
    if (
        not (isinstance(config.settle_steps, int) and not isinstance(config.settle_steps, bool))
        or config.settle_steps < 0
    ):
        raise KitbenchError(f"settle_steps must be an integer >= 0, got {config.settle_steps!r}")
    interval = config.commit_interval
    # nan compares false with everything: a recording asked to commit every nan seconds would never commit
    if not (isinstance(interval, int | float) and not isinstance(interval, bool) and 0 <= interval < math.inf):
        raise KitbenchError(f"commit_interval must be a finite number of seconds >= 0, got {interval!r}")
    if config.max_attempts is not None and not (
        _is_count(config.max_attempts) and config.max_attempts >= config.episodes
    ):
        raise KitbenchError(
            f"max_attempts must be a positive integer >= episodes ({config.episodes}), got {config.max_attempts!r}"
        )
    if config.repo_id is not None:
        check_repo_id(config.repo_id)
    if config.resume and config.overwrite:
        raise KitbenchError("--resume and --overwrite exclude each other")
    config.executor_config.validate()
    if not (isinstance(config.shard_episodes, int) and not isinstance(config.shard_episodes, bool)) or (
        config.shard_episodes < 0
    ):
        raise KitbenchError(f"shard_episodes must be an integer >= 0, got {config.shard_episodes!r}")
    if config.shard_episodes and config.only_success:
        raise KitbenchError(
            "shard_episodes and only_success exclude each other: which seeds a shard keeps would depend on the "
            "shard size; record all episodes, or record without shards"
        )
    _check_output(config)
    from kitbench.doctor import require_renderer

    require_renderer(config.obs_mode)
    if config.source is not None:
        _check_source(config)
        return
    env = make_recording_env(config)  # raises on a bad control mode, robot or task setting
    try:
        from kitbench.policies.registry import make_policy

        policy = make_policy(config.policy)
        if config.policy == "expert" or config.label == "expert":
            from kitbench.policies.expert import check_has_expert

            check_has_expert(env)
        _check_policy_fits(config, policy, env)
        del policy
    finally:
        env.close()


def _check_source(config: RecordConfig) -> None:
    """A conversion's source is a kitbench recording of this task, replayed without noise of its own."""
    from kitbench.recording.source import SourceRecording

    source = SourceRecording(config.source)  # type: ignore[arg-type]  # only called with one
    if source.settings["task"] != config.task:
        raise KitbenchError(f"{config.source} records {source.settings['task']}, not {config.task}")
    if config.action_noise or config.label is not None:
        raise KitbenchError("a conversion replays its source's actions: no action_noise or label of its own")
    if config.shard_episodes:
        raise KitbenchError("a conversion runs its source's seeds on one writer: drop shard_episodes")
    env = make_recording_env(config)  # raises on a bad obs mode, control mode or robot
    env.close()


LABELS = ("expert",)


def _check_label(config: RecordConfig) -> None:
    if config.label is None:
        return
    if config.label not in LABELS:
        raise KitbenchError(f"unknown label {config.label!r}; valid choices: {', '.join(LABELS)}")
    if config.policy == config.label:
        raise KitbenchError(f"label {config.label!r} labels policy {config.policy!r} with itself; drop --label")


def _check_policy_fits(config: RecordConfig, policy, env) -> None:
    """A trained policy records in the modes and on the robot it was trained for (`requirements()`), asked for
    explicitly: a dataset's settings are the command's, never silently the checkpoint's. Then its own check on
    the env (inputs and action size)."""
    needs = policy.requirements() if hasattr(policy, "requirements") else {}
    u = env.unwrapped
    asked = {"control_mode": config.control_mode, "robot": u.robot_uid, "obs_mode": config.obs_mode}
    flags = {"control_mode": "--control-mode", "robot": "--robot", "obs_mode": "--obs-mode"}
    for key, value in needs.items():
        if key in asked and value != asked[key]:
            if key == "obs_mode" and camera_textures(value) <= camera_textures(config.obs_mode):
                continue  # the recording asks for more than the policy reads: it gets what it reads
            raise KitbenchError(
                f"policy {config.policy} needs {key} {value} (recording asks for {asked[key]}); record with "
                f"{flags[key]} {value}"
            )
    if hasattr(policy, "check"):
        policy.check(env)


def _check_noise_phases(config: RecordConfig) -> None:
    """`noise_phases` names phases of the task's expert, for a recording with noise, run by that expert."""
    phases = config.noise_phases
    if phases is None:
        return
    if not (isinstance(phases, tuple) and phases and all(isinstance(p, str) for p in phases)):
        raise KitbenchError(f"noise_phases must be a non-empty list of phase names, got {phases!r}")
    if not config.action_noise:
        raise KitbenchError("noise_phases needs action_noise > 0: it names the expert phases the noise runs in")
    if config.policy != "expert":
        raise KitbenchError(f"noise_phases names phases of the expert; policy {config.policy!r} has none")
    expert = task_entry(config.task).env_class.expert_class(config.robot)
    valid = getattr(expert, "phases", ())
    if not valid:
        raise KitbenchError(f"noise_phases: the {config.task} expert declares no phases (`PhasePlanner.phases`)")
    for phase in phases:
        if phase not in valid:
            raise KitbenchError(
                f"unknown noise phase {phase!r} for the {config.task} expert; valid choices: {', '.join(valid)}"
            )


def _is_count(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 1


def check_repo_id(repo_id) -> None:
    """Refuse a repo id the Hugging Face Hub would refuse (lerobot writes it into the dataset and pushes under it)."""
    from huggingface_hub.errors import HFValidationError

    # public, but re-exported through a computed __all__ that mypy cannot read
    from huggingface_hub.utils import validate_repo_id  # type: ignore[attr-defined]

    try:
        validate_repo_id(repo_id)
    except HFValidationError as exc:
        # the hub's message ends by quoting the id and may advise on an argument the command line does not have
        reason = (
            str(exc).splitlines()[0].replace(f": '{repo_id}'", "").replace(" Use `repo_type` argument if needed.", "")
        )
        raise KitbenchError(f"invalid repo_id {repo_id!r}: {reason[:1].lower()}{reason[1:]}") from None


def _leftovers(out: Path) -> list[Path]:
    """What a recording at `out` leaves besides the dataset folder: the folders of a commit a kill interrupted
    (restored by the recorder) and the journal of episodes not yet committed (a kill before the first commit
    leaves only that)."""
    from kitbench.recording.dataset import RETIRED_SUFFIX
    from kitbench.recording.journal import journal_root

    return [p for p in (out.with_name(out.name + RETIRED_SUFFIX), journal_root(out)) if p.is_dir()]


def _saved_settings(out: Path) -> list[dict]:
    """The settings each part of an interrupted recording at `out` was made with."""
    from kitbench.recording.dataset import RETIRED_SUFFIX, SESSION_SUFFIX
    from kitbench.recording.journal import SETTINGS_FILE, journal_root

    candidates = [out / RECORDING_FILE]
    if not out.exists():  # killed inside a commit: the recorder restores the session, else the retired folder
        session, retired = (out.with_name(out.name + suffix) for suffix in (SESSION_SUFFIX, RETIRED_SUFFIX))
        candidates = [(session if session.is_dir() else retired) / RECORDING_FILE]
    candidates.append(journal_root(out) / SETTINGS_FILE)
    saved = []
    for path in candidates:
        if path.is_file():
            try:
                saved.append(json.loads(path.read_text()))
            except (OSError, json.JSONDecodeError) as exc:
                raise KitbenchError(f"cannot resume {out}: {path} is unreadable ({exc})") from exc
    return saved


def _check_output(config: RecordConfig) -> None:
    """The output folder fits what was asked: new, or an unfinished recording to --resume, or one to --overwrite."""
    out = config.out
    blocker = next((p for p in (out, *out.parents) if p.exists() or p.is_symlink()), None)
    if blocker is not None and not blocker.is_dir():
        where = "" if blocker == out else f" ({blocker} is a file)"
        raise KitbenchError(f"output {out} is not a folder{where}; give --out a folder path")
    leftovers = _leftovers(out)
    if not config.resume and not config.overwrite:
        if out.exists():
            raise KitbenchError(
                f"output folder {out} exists; pass --resume to continue it or --overwrite to replace it"
            )
        if leftovers:
            raise KitbenchError(
                f"an unfinished recording of {out} exists ({leftovers[0]}); pass --resume to continue it or "
                "--overwrite to replace it"
            )
    if not config.resume:
        return
    from kitbench.recording.journal import SHARDS_DIR, journal_root

    if (journal_root(out) / SHARDS_DIR).is_dir() and not config.shard_episodes:
        raise KitbenchError(f"{out} is an unfinished sharded recording; resume it with --shard-episodes N")
    if not out.exists() and not leftovers:
        raise KitbenchError(f"nothing to resume at {out} (drop --resume to start one)")
    if out.exists() and not (out / RECORDING_FILE).is_file():
        raise KitbenchError(f"cannot resume {out}: it is not a kitbench recording ({RECORDING_FILE} missing)")
    for saved in _saved_settings(out):
        identity = config.identity()
        recorded = {k: saved.get(k, RECORDED_BEFORE.get(k)) for k in identity}
        mismatched = {k: (recorded[k], v) for k, v in identity.items() if recorded[k] != v}
        if mismatched:
            detail = ", ".join(f"{k}: recorded {a!r}, asked {b!r}" for k, (a, b) in mismatched.items())
            raise KitbenchError(f"cannot resume {out} with different settings ({detail})")


def make_recording_env(config: RecordConfig):
    from kitbench.registration import make_env

    return make_env(
        config.task,
        obs_mode=config.obs_mode,
        control_mode=config.control_mode,
        reward_mode=config.reward_mode,
        robot_uids=config.robot,
    )
