"""What kitbench keeps of its own in a LeRobot dataset, read and written here only.

`meta/kitbench_recording.json` holds the recording's settings (`RecordingInfo`: task, modes, policy, seeds, the
kitbench version and this file's format); `meta/kitbench_episodes.jsonl` one line per episode (`EpisodeInfo`: seed,
success, length, the task's episode configuration). Every reader goes through `RecordingInfo.read` and
`read_episodes`, so a recording made by an older kitbench reads with what its missing settings meant then.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from kitbench.errors import KitbenchError

RECORDING_FILE = "meta/kitbench_recording.json"
EPISODES_FILE = "meta/kitbench_episodes.jsonl"
# 1: files written before the format was numbered (they read the same); 2: numbered.
FORMAT = 2
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
    "rgb_storage",
    "label",
    "source",
    "kitbench_version",
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
    rgb_storage: str = "video"
    label: str | None = None  # who labelled each frame's action (DAgger); None: the acting policy
    source: str | None = None  # the recording a conversion re-simulated
    kitbench_version: str | None = None  # None: made before 0.2.0
    repo_id: str | None = None
    fps: int | None = None
    seeds: list[int] | None = None  # the episodes' seeds when not consecutive (`kitbench eval --save-dataset`)
    made_by: str | None = None  # the command that made it, when not `kitbench record` with these settings
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
        """The settings of the recording at `root`; None for a dataset kitbench did not record."""
        path = Path(root) / RECORDING_FILE
        if not path.is_file():
            return None
        try:
            return cls.from_json(json.loads(path.read_text()))
        except (OSError, ValueError, TypeError) as exc:
            raise KitbenchError(f"{path} is unreadable ({exc})") from None

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
        optional = ("pointcloud_points", "label", "source", "repo_id", "fps", "seeds", "made_by")
        data = {k: v for k, v in data.items() if not (k in optional and v is None)}
        return {**data, **self.extra}

    def write(self, root: str | Path) -> None:
        path = Path(root) / RECORDING_FILE
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps({**self.to_json(), "format": FORMAT}, indent=2) + "\n")

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

    @classmethod
    def from_json(cls, data: dict) -> EpisodeInfo:
        named = {f.name for f in dataclasses.fields(cls)} - {"config"}
        return cls(**{k: data[k] for k in named if k in data}, config={k: v for k, v in data.items() if k not in named})

    def to_json(self) -> dict:
        data = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "config"}
        return {**data, **self.config}


def read_episodes(root: str | Path) -> list[EpisodeInfo]:
    path = Path(root) / EPISODES_FILE
    if not path.is_file():
        return []
    return [EpisodeInfo.from_json(json.loads(line)) for line in path.read_text().splitlines() if line.strip()]


def write_episodes(root: str | Path, episodes: list[EpisodeInfo]) -> None:
    path = Path(root) / EPISODES_FILE
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("".join(json.dumps(e.to_json()) + "\n" for e in episodes))


def is_recording(root: str | Path) -> bool:
    return (Path(root) / RECORDING_FILE).is_file()


def read_recording_settings(root: str | Path) -> dict | None:
    """The recording's settings as a plain dict (for reports and printing); None for a dataset kitbench did not
    record."""
    info = RecordingInfo.read(root)
    return None if info is None else info.to_json()
