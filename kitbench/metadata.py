"""What kitbench keeps of its own in a LeRobot dataset, read and written here only.

`meta/kitbench_recording.json` holds the recording's settings (`RecordingInfo`: task, modes, policy, seeds, the
kitbench version and this file's format); `meta/kitbench_episodes.jsonl` one line per episode (`EpisodeInfo`: seed,
success, length, the task's episode configuration). Every reader goes through `RecordingInfo.read` and
`read_episodes`, so a recording made by an older kitbench reads with what its missing settings meant then.

LeRobot's own tools (`lerobot-edit-dataset`, `aggregate_datasets`) drop both files and every key of their own in
`meta/info.json`, but copy each feature's entry whole and every data column. So the settings are also carried in
the `episode_seed` feature's entry (`CARRIER`), and each episode's facts are read back from its columns
(`episode_seed`, `next.success`), its task from LeRobot's episode index and its configuration from its seed
(docs/recording.md, "After LeRobot's tools").
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from kitbench.errors import KitbenchError

RECORDING_FILE = "meta/kitbench_recording.json"
EPISODES_FILE = "meta/kitbench_episodes.jsonl"
INFO_FILE = "meta/info.json"  # LeRobot's
# The per-frame feature whose entry in meta/info.json carries the recording's settings (under "info" -> "kitbench").
CARRIER = "episode_seed"
# Settings that are not carried: merged recordings differ in them (LeRobot's merge wants equal feature entries).
NOT_CARRIED = ("seed",)
# 1: files written before the format was numbered (they read the same); 2: numbered.
FORMAT = 2
# What an action means and how the scene answers it: ManiSkill 3.0.1's (its gripper +1 opens; its Panda's drive
# gains and default material: docs/fidelity.md). A recording without one was made before (`action_convention`).
ACTION_CONVENTION = "maniskill-3.0.1"
# The settings a resumed recording must share with its first part (and shards with each other): episodes are
# reproducible from their seed only under the same settings and the same kitbench (its physics and assets).
IDENTITY = (
    "task",
    "seed",
    "obs_mode",
    "control_mode",
    "policy",
    "only_success",
    "action_noise",
    "noise_phases",
    "settle_steps",
    "reward_mode",
    "robot",
    "pointcloud_points",
    "camera_size",
    "camera_view",
    "rgb_storage",
    "label",
    "expert_options",
    "source",
    "kitbench_version",
    "action_convention",
)


@dataclass
class RecordingInfo:
    """A recording's settings, as `meta/kitbench_recording.json` stores them. A setting an older file lacks reads
    as what it meant then (the defaults below)."""

    task: str
    seed: int = 0
    obs_mode: str = "state"
    control_mode: str = "pd_joint_delta_pos"
    policy: str = "expert"
    only_success: bool = False
    action_noise: float = 0.0
    noise_phases: list[str] | None = None  # None: noise in every phase
    settle_steps: int = 0
    reward_mode: str = "dense"
    robot: str | None = None  # None: the task's default robot
    pointcloud_points: int | None = None  # kept for obs_mode pointcloud only
    camera_size: str | None = None  # "WxH" when not the cameras' own size
    camera_view: str | None = None  # the task's named framing of its cameras; None: its own (ManiSkill's)
    rgb_storage: str = "video"
    label: str | None = None  # who labelled each frame's action (DAgger); None: the acting policy
    expert_options: dict[str, Any] | None = None  # the expert's config fields a recording replaced (close_steps=6)
    # A person's recording (`teleop:<device>`): the device's options and the source's (port, id, display, ...), less
    # anything secret; the device's type is the policy's
    teleop_options: dict[str, Any] | None = None
    source: str | None = None  # the recording a conversion re-simulated
    kitbench_version: str | None = None  # None: made before 0.2.0
    # None: made before ACTION_CONVENTION (gripper +1 closed; stiffer arm drives, a grippier peg)
    action_convention: str | None = None
    repo_id: str | None = None
    fps: int | None = None
    seeds: list[int] | None = None  # the episodes' seeds when not consecutive (`kitbench eval --save-dataset`)
    made_by: str | None = None  # the command that made it, when not `kitbench record` with these settings
    episodes_sha256: str | None = None  # EPISODES_FILE's digest when this file was written beside it (`write`)
    features_sha256: str | None = None  # the digest of INFO_FILE's features then (`features_digest`)
    format: int = 1
    extra: dict[str, Any] = field(default_factory=dict)  # keys this kitbench does not know (a newer one's)

    # -- reading ---------------------------------------------------------------------------------
    @classmethod
    def from_json(cls, data: dict) -> RecordingInfo:
        known = {f.name for f in dataclasses.fields(cls)} - {"extra"}
        if "task" not in data:
            raise KitbenchError(f"{RECORDING_FILE} names no task")
        info = cls(**{k: v for k, v in data.items() if k in known})
        info.extra = {k: v for k, v in data.items() if k not in known}
        return info

    @classmethod
    def read(cls, root: str | Path) -> RecordingInfo | None:
        """The settings of the recording at `root`: its settings file, else what its `CARRIER` feature carries
        (after LeRobot's tools, the first seed read from the data); None for a dataset kitbench did not record."""
        path = Path(root) / RECORDING_FILE
        if not path.is_file():
            return cls.from_features(Path(root))
        try:
            return cls.from_json(json.loads(path.read_text()))
        except (OSError, ValueError, TypeError) as exc:
            raise KitbenchError(f"{path} is unreadable ({exc})") from None

    @classmethod
    def from_features(cls, root: Path, seeds: list[int] | None = None) -> RecordingInfo | None:
        """`seeds`: the episodes' seeds when the caller has read them already."""
        lerobot = lerobot_info(root)
        carried = carried_settings(lerobot)
        if carried is None or not (root / "meta" / "episodes").is_dir():
            return None  # not kitbench's, or a LeRobot session never finalized (a killed first commit)
        if seeds is None:
            seeds = [e.seed for e in _episodes_from_data(root, [])]
        try:
            info = cls.from_json({**carried, "seed": min(seeds, default=0), "fps": lerobot.get("fps")})
        except TypeError as exc:
            raise KitbenchError(
                f"{root / INFO_FILE}: the settings in feature {CARRIER} are unreadable ({exc})"
            ) from None
        return info.holding(seeds)

    def require_current(self, root: str | Path) -> RecordingInfo:
        """These settings, unless the recording's actions mean something else here (`ACTION_CONVENTION`): then one
        line naming `kitbench convert` as the remedy."""
        if self.action_convention != ACTION_CONVENTION:
            made = f"kitbench's earlier one ({self.kitbench_version or 'before 0.2.0'}: gripper +1 closed)"
            raise KitbenchError(
                f"{root} was recorded in {made if self.action_convention is None else self.action_convention!r}, "
                f"not ManiSkill's ({ACTION_CONVENTION}: gripper +1 opens, its dynamics); migrate it with "
                f"kitbench convert {root} --out NEW_FOLDER"
            )
        return self

    @classmethod
    def require(cls, root: str | Path, what: str = "") -> RecordingInfo:
        info = cls.read(root)
        if info is None:
            raise KitbenchError(f"{what or root} is not a kitbench recording ({RECORDING_FILE} missing)")
        return info

    # -- writing ---------------------------------------------------------------------------------
    def to_json(self) -> dict:
        """What the file holds: every setting, less those a recording of its kind never had (None past the
        identity's end), plus any unknown keys kept from the file it was read from."""
        data = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "extra"}
        optional = (
            "pointcloud_points",
            "camera_size",
            "camera_view",
            "label",
            "expert_options",
            "teleop_options",
            "source",
            "action_convention",
            "repo_id",
            "fps",
            "seeds",
            "made_by",
            "episodes_sha256",
            "features_sha256",
        )
        data = {k: v for k, v in data.items() if not (k in optional and v is None)}
        return {**data, **self.extra}

    def write(self, root: str | Path) -> None:
        """Write the settings file at `root`, with the digests of the episode file and of LeRobot's features written
        there before it (which `kitbench.integrity` checks: either edited afterwards is refused, not believed)."""
        path = Path(root) / RECORDING_FILE
        episodes = Path(root) / EPISODES_FILE
        digests = {
            "episodes_sha256": episodes_digest(episodes.read_bytes()) if episodes.is_file() else None,
            "features_sha256": features_digest(lerobot_info(Path(root)).get("features")),
        }
        data = {k: v for k, v in self.to_json().items() if k not in (*digests, "format")}
        data = {**data, **digests, "format": FORMAT}
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps({k: v for k, v in data.items() if v is not None}, indent=2) + "\n")

    def implied_seeds(self, count: int) -> list[int]:
        """The seeds of `count` episodes as these settings say them: their list, else consecutive from `seed`."""
        return self.seeds or list(range(self.seed, self.seed + count))

    def holding(self, seeds: list[int]) -> RecordingInfo:
        """These settings for a recording whose episodes are of `seeds`, in order: the list kept where they are not
        the ones the settings imply, as after a seed whose simulation failed or a conversion's episode that diverged
        from its source."""
        if list(seeds) == self.implied_seeds(len(seeds)):
            return self
        return dataclasses.replace(self, seeds=list(seeds))

    def validate(self) -> None:
        """Each setting has its type (a file edited by hand may not): a one-line `KitbenchError` naming it."""
        for name, kinds in _SETTING_TYPES.items():
            value = getattr(self, name)
            if not isinstance(value, kinds) or (isinstance(value, bool) and bool not in kinds):
                raise KitbenchError(f"{RECORDING_FILE}: {name} is {value!r}, not a valid value")
        for name in ("noise_phases", "seeds"):
            items = getattr(self, name)
            kind = str if name == "noise_phases" else int
            if items is not None and not all(isinstance(v, kind) and not isinstance(v, bool) for v in items):
                raise KitbenchError(f"{RECORDING_FILE}: {name} is {items!r}, not a valid value")
        if not 1 <= self.format <= FORMAT:
            raise KitbenchError(f"{RECORDING_FILE}: format {self.format} is not one this kitbench reads (1..{FORMAT})")

    def carried(self) -> dict:
        """The settings the `CARRIER` feature's entry holds: those every part of a merged recording shares."""
        data = self.to_json()
        return {"format": FORMAT, **{k: v for k, v in data.items() if k in IDENTITY and k not in NOT_CARRIED}}

    def carry(self, features: dict) -> dict:
        """`features` with this recording's settings in the `CARRIER` feature's entry."""
        entry = features[CARRIER]
        return {**features, CARRIER: {**entry, "info": {**entry.get("info", {}), "kitbench": self.carried()}}}

    # -- comparing -------------------------------------------------------------------------------
    def identity(self) -> dict:
        return {k: getattr(self, k) for k in IDENTITY}

    def differences(self, other: RecordingInfo, ignore: tuple[str, ...] = ()) -> dict[str, tuple[Any, Any]]:
        """The identity settings in which `other` differs from this one: name -> (this, other)."""
        mine, theirs = self.identity(), other.identity()
        return {k: (mine[k], theirs[k]) for k in IDENTITY if k not in ignore and mine[k] != theirs[k]}

    @property
    def robot_uid(self) -> str:
        from kitbench.registration import task_entry

        return self.robot or task_entry(self.task).env_class.supported_robots[0]


_NONE = type(None)
# The type of each setting a settings file may hold (`RecordingInfo.validate`).
_SETTING_TYPES: dict[str, tuple[type, ...]] = {
    "task": (str,),
    "seed": (int,),
    "obs_mode": (str,),
    "control_mode": (str,),
    "policy": (str,),
    "only_success": (bool,),
    "action_noise": (int, float),
    "noise_phases": (list, _NONE),
    "settle_steps": (int,),
    "reward_mode": (str,),
    "robot": (str, _NONE),
    "pointcloud_points": (int, _NONE),
    "camera_size": (str, _NONE),
    "camera_view": (str, _NONE),
    "rgb_storage": (str,),
    "label": (str, _NONE),
    "expert_options": (dict, _NONE),
    "teleop_options": (dict, _NONE),
    "source": (str, _NONE),
    "kitbench_version": (str, _NONE),
    "action_convention": (str, _NONE),
    "repo_id": (str, _NONE),
    "fps": (int, _NONE),
    "seeds": (list, _NONE),
    "made_by": (str, _NONE),
    "episodes_sha256": (str, _NONE),
    "features_sha256": (str, _NONE),
    "format": (int,),
}


def expert_options(policy: str, options) -> dict[str, Any] | None:
    """What a recording keeps as `expert_options`: the `--policy-option` pairs when the expert acts (they are its
    planner's settings), else None (a checkpoint's or a teleoperator's options are not the expert's)."""
    return (dict(options) or None) if policy == "expert" else None


# Option names a recording never keeps (a device's credentials, should one take them).
SECRET_WORDS = ("token", "secret", "password", "passwd", "key", "credential")


def teleop_options(policy: str, options) -> dict[str, Any] | None:
    """What a recording keeps as `teleop_options`: the `--policy-option` pairs of a teleoperated recording (the
    device's port, id, ... and the source's own), less any whose name says it is secret; else None."""
    if policy.partition(":")[0] != "teleop":
        return None
    kept = {k: v for k, v in dict(options).items() if not any(w in k.lower() for w in SECRET_WORDS)}
    return kept or None


def episodes_digest(data: bytes) -> str:
    """The digest of an episode file's bytes, as the settings file keeps it."""
    return hashlib.sha256(data).hexdigest()


def features_digest(features: dict | None) -> str | None:
    """The digest of LeRobot's feature entries (whatever their key order), as the settings file keeps it."""
    if features is None:
        return None
    return hashlib.sha256(json.dumps(features, sort_keys=True).encode()).hexdigest()


@dataclass
class EpisodeInfo:
    """One line of `meta/kitbench_episodes.jsonl`: what LeRobot has no place for."""

    episode_index: int
    seed: int
    success: bool
    length: int
    first_success: int | None = None
    task: str | None = None  # the instruction
    config: dict[str, Any] = field(default_factory=dict)  # the task's episode configuration, modes included
    # A person's episode (`teleop:<device>`): how it ended (`ended`: key, with the `key`, success, limit), the values
    # clipped to the joint limits and the steps rate-limited to the joint speeds; None for a policy's.
    teleop: dict[str, Any] | None = None

    @classmethod
    def from_json(cls, data: dict) -> EpisodeInfo:
        named = {f.name for f in dataclasses.fields(cls)} - {"config"}
        return cls(**{k: data[k] for k in named if k in data}, config={k: v for k, v in data.items() if k not in named})

    def to_json(self) -> dict:
        data = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "config"}
        if self.teleop is None:
            del data["teleop"]  # a policy's episode reads as it always did
        return {**data, **self.config}

    def validate(self) -> None:
        """Each fact has its type (a file edited by hand may not): a one-line `KitbenchError` naming it."""

        def whole(v: object) -> bool:
            return isinstance(v, int) and not isinstance(v, bool)

        checks = {
            "episode_index": whole(self.episode_index) and self.episode_index >= 0,
            "seed": whole(self.seed),
            "success": isinstance(self.success, bool),
            "length": whole(self.length) and self.length > 0,
            "first_success": self.first_success is None or whole(self.first_success),
            "task": self.task is None or isinstance(self.task, str),
            "teleop": self.teleop is None or isinstance(self.teleop, dict),
        }
        for name, ok in checks.items():
            if not ok:
                raise KitbenchError(f"{name} is {getattr(self, name)!r}, not a valid value")


def read_episode_file(root: str | Path) -> list[EpisodeInfo]:
    """The lines of `EPISODES_FILE` as written (the writer's own view, before its commit)."""
    path = Path(root) / EPISODES_FILE
    if not path.is_file():
        return []
    return [EpisodeInfo.from_json(json.loads(line)) for line in path.read_text().splitlines() if line.strip()]


def read_episodes(root: str | Path) -> list[EpisodeInfo]:
    """The episodes of the recording at `root`, in episode order: `EPISODES_FILE` while it describes the dataset
    (its tasks as LeRobot's index now names them), else each episode's facts read back from the dataset."""
    root = Path(root)
    lines = read_episode_file(root)
    lerobot = lerobot_info(root)
    total = lerobot.get("total_episodes")
    if total is None or (len(lines) == total and [e.episode_index for e in lines] == list(range(total))):
        tasks = _episode_tasks(root)
        for episode in lines:
            episode.task = tasks.get(episode.episode_index, episode.task)
        return lines
    episodes = _episodes_from_data(root, lines)
    missing = [e for e in episodes if not e.config]
    info = None
    if missing:  # the settings file is gone or stale with the episodes file: the seeds are read already
        info = RecordingInfo.from_features(root, [e.seed for e in episodes]) or RecordingInfo.read(root)
    if info is not None:
        for episode, config in zip(missing, _configs_of(info, [e.seed for e in missing]), strict=True):
            episode.config = config
    return episodes


def _configs_of(info: RecordingInfo, seeds: list[int]) -> list[dict]:
    """What each seed chose (`task_config`, as the recording wrote it), from the task itself: a reset per seed."""
    from kitbench.registration import make_env

    env = make_env(info.task, obs_mode="state", control_mode=info.control_mode, robot_uids=info.robot_uid)
    try:
        configs = []
        for seed in seeds:
            env.reset(seed=seed)
            configs.append({"control_mode": info.control_mode, "obs_mode": info.obs_mode, **env.episode_config()})
        return configs
    finally:
        env.close()


def lerobot_info(root: Path) -> dict:
    path = root / INFO_FILE
    if not path.is_file():
        return {}
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise KitbenchError(f"{path} is unreadable ({exc})") from None


def read_columns(files: list[Path], columns: list[str]):
    """`columns` of the parquet `files`, one pandas frame. Read by path through pyarrow's own file system: pandas'
    `read_parquet` hands pyarrow a Python file object, whose buffers pyarrow's I/O threads may release after the
    interpreter began to exit, aborting the process ("terminate called without an active exception", exit 134)."""
    import pandas as pd
    import pyarrow.parquet as pq

    return pd.concat([pq.read_table(str(f), columns=columns).to_pandas() for f in files])


def _episode_tasks(root: Path) -> dict[int, str]:
    """Each episode's task as LeRobot's episode index (`meta/episodes/`) holds it."""
    files = sorted((root / "meta" / "episodes").rglob("*.parquet"))
    if not files:
        return {}
    table = read_columns(files, ["episode_index", "tasks"])
    return {int(i): str(next(iter(t))) for i, t in zip(table["episode_index"], table["tasks"], strict=True) if len(t)}


def _episodes_from_data(root: Path, known: list[EpisodeInfo]) -> list[EpisodeInfo]:
    """Each episode's seed, success and length from its columns, its task from LeRobot's index; its configuration
    from `known` (a stale episodes file) by seed, else from the task given that seed (`episode_config`)."""
    import numpy as np
    import pyarrow.parquet as pq

    files = sorted((root / "data").rglob("*.parquet"))
    if not files:
        return []
    wanted = ["episode_index", CARRIER, "next.success"]
    columns = [c for c in wanted if c in pq.read_schema(files[0]).names]
    if CARRIER not in columns:
        raise KitbenchError(f"{root} has no {CARRIER} column: its episodes' seeds are lost")
    frames = read_columns(files, columns)
    tasks = _episode_tasks(root)
    by_seed = {e.seed: e for e in known}
    episodes = []
    for index, group in frames.groupby("episode_index", sort=True):
        seed = int(np.ravel(group[CARRIER].iloc[0])[0])  # (1,) features read back as scalars or arrays
        old = by_seed.get(seed)
        successes = [bool(np.ravel(v)[0]) for v in group["next.success"]] if "next.success" in columns else []
        first = successes.index(True) if True in successes else None
        if not successes and old is not None:
            first = old.first_success
        episodes.append(
            EpisodeInfo(
                int(index), seed, first is not None, len(group), first, tasks.get(int(index)), old.config if old else {}
            )
        )
    return episodes


def write_episodes(root: str | Path, episodes: list[EpisodeInfo]) -> None:
    path = Path(root) / EPISODES_FILE
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("".join(json.dumps(e.to_json()) + "\n" for e in episodes))


def is_recording(root: str | Path) -> bool:
    """Whether kitbench recorded the dataset at `root` (its settings file, or the settings its features carry)."""
    root = Path(root)
    if (root / RECORDING_FILE).is_file():
        return True
    return carried_settings(lerobot_info(root)) is not None


def carried_settings(lerobot: dict) -> dict | None:
    """The recording's settings the `CARRIER` feature's entry in LeRobot's info carries; None without them."""
    carried: Any = lerobot
    for key in ("features", CARRIER, "info", "kitbench"):  # any level may be missing, or edited into a non-object
        carried = carried.get(key) if isinstance(carried, dict) else None
    return carried if isinstance(carried, dict) else None


def read_recording_settings(root: str | Path) -> dict | None:
    """The recording's settings as a plain dict (for reports and printing); None for a dataset kitbench did not
    record."""
    info = RecordingInfo.read(root)
    return None if info is None else info.to_json()
