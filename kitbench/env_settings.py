"""The settings that choose an env, declared once for the command line, recipes, suites and the LeRobot plugin
(`kitbench.config`): which task on which robot, driven how (`TaskSettings`); how many points a point cloud keeps,
the last thing a trained policy needs matched (`PolicyEnvSettings`, the plugin's); observed and rewarded how
(`EnvSettings`). One chain of classes, so that draccus finds each inherited field's help (its comment) as it does
for lerobot's own configs."""

from __future__ import annotations

from dataclasses import dataclass

from kitbench.config.checks import one_of, optional, positive_int
from kitbench.config.declare import setting
from kitbench.control.controllers import CONTROL_MODES
from kitbench.envs.modes import IMAGE_OBS_MODES, REWARD_MODES
from kitbench.envs.pointcloud import DEFAULT_POINTS
from kitbench.errors import KitbenchError
from kitbench.registration import TASKS, canonical_task, task_entry
from kitbench.sim.cameras import OBSERVATION_SIZE

# What a recording stores and a suite scores: the state alone, or what the cameras give (a point cloud included).
OBS_MODES = ("state", *IMAGE_OBS_MODES)


def parse_size(text: str) -> tuple[int, int]:
    """`WxH` or `N` (N x N) as (width, height); a bad value is one line."""
    parts = str(text).lower().split("x")
    if len(parts) in (1, 2) and all(p.isdigit() and 8 <= int(p) <= 4096 for p in parts):
        return int(parts[0]), int(parts[-1])
    raise KitbenchError(
        f"camera_size must be WIDTHxHEIGHT or one side, 8 to 4096 pixels (e.g. 64x64 or 96), got {text!r}"
    )


def canonical_size(text: object) -> str | None:
    """One spelling of a camera size, so that settings compare: "WxH", and None for the cameras' own
    (`OBSERVATION_SIZE`), however it was asked for (64 and "64x64" are the same; so are None and "128x128")."""
    if text is None:
        return None
    size = parse_size(text)  # type: ignore[arg-type]
    return None if size == OBSERVATION_SIZE else f"{size[0]}x{size[1]}"


def _size(name: str, value: object) -> None:
    parse_size(value)  # type: ignore[arg-type]


def _task(name: str, value: object) -> None:
    if value is not None:
        task_entry(value)  # type: ignore[arg-type]  # one line naming every registered task


@dataclass
class TaskSettings:
    # A kitbench task: LiftPegUpright-v1 or AssemblingKits-v1 (any task registered with kitbench), or its gym id
    # kitbench/<task>.
    task: str | None = setting(None, check=_task)
    # One of the task's robots (default: its first, e.g. panda; or fetch).
    robot: str | None = setting(None)
    # The action space: pd_joint_pos, pd_joint_delta_pos, pd_ee_delta_pose, ...; a trained policy must act in the
    # one its training dataset was recorded in. Absolute joint targets by default (the env's own default is
    # ManiSkill's pd_joint_delta_pos): the mode ManiSkill's solutions act in, and in which the experts finish
    # LiftPegUpright within its 50 steps under ManiSkill's drives (docs/fidelity.md).
    control_mode: str = setting("pd_joint_pos", check=one_of(CONTROL_MODES))

    def __post_init__(self) -> None:
        # stored by its short name (a gym id `kitbench/<task>` is accepted), so settings compare whatever the spelling
        if self.task is not None:
            self.task = canonical_task(self.task)

    @property
    def task_id(self) -> str:
        """The task (settings that name none are refused before anything runs)."""
        if self.task is None:
            raise KitbenchError("missing --task")
        return self.task

    @property
    def robot_uid(self) -> str:
        """The robot: the one asked for, else the task's default."""
        return self.robot or task_entry(self.task_id).env_class.supported_robots[0]

    def check_robot(self) -> None:
        """The robot is one the task supports."""
        if self.robot is None or self.task not in TASKS:
            return
        supported = TASKS[self.task].env_class.supported_robots
        if self.robot not in supported:
            raise KitbenchError(
                f"robot {self.robot!r} is not supported by {self.task}; valid choices: {', '.join(supported)}"
            )


@dataclass
class PolicyEnvSettings(TaskSettings):
    # Points per frame with obs_mode pointcloud, sampled with the episode's seed (as a dataset stores them).
    pointcloud_points: int = setting(DEFAULT_POINTS, check=positive_int)
    # Every observation camera's image, WIDTHxHEIGHT pixels (one number: a square), each camera keeping its field of
    # view (default: the task's and robot's own, 128x128). A policy is scored at the size it was trained at.
    camera_size: str | None = setting(None, check=optional(_size), metavar="WxH")
    # Another framing of the observation cameras, by the name the task declares it under (AssemblingKits: board, its
    # base camera in front of the board; LiftPegUpright: peg, the base camera or the SO-101's front camera nearer
    # the peg); default: the cameras as ManiSkill and the robot frame them. A policy is scored in the framing it was
    # trained in.
    camera_view: str | None = setting(None, metavar="NAME")

    def __post_init__(self) -> None:
        super().__post_init__()
        self.camera_size = canonical_size(self.camera_size)

    def check_camera_view(self) -> None:
        """The view is one the task declares, and frames at least one camera the task has with this robot."""
        self._view_framings()

    def _view_framings(self) -> dict[str, dict]:
        """The view's framings of the cameras the task has with this robot ({} without a view)."""
        if self.camera_view is None or self.task not in TASKS:
            return {}
        env_class = TASKS[self.task].env_class
        views = env_class.camera_views
        if self.camera_view not in views:
            raise KitbenchError(
                f"camera_view {self.camera_view!r} is not one of {self.task}'s; valid choices: "
                f"{', '.join(views) or '(none: the task declares no other view)'}"
            )
        self.check_robot()
        cameras = env_class.observation_cameras(self.robot_uid)
        framings = {camera: dict(v) for camera, v in views[self.camera_view].items() if camera in cameras}
        if not framings:
            raise KitbenchError(
                f"camera_view {self.camera_view!r} frames none of {self.task}'s cameras with robot {self.robot_uid} "
                f"({', '.join(cameras)}); drop --camera-view"
            )
        return framings

    @property
    def sensor_configs(self) -> dict | None:
        """`camera_size` and `camera_view` as the env's (ManiSkill's) `sensor_configs`."""
        configs: dict = {}
        if self.camera_size is not None:
            width, height = parse_size(self.camera_size)
            configs.update(width=width, height=height)
        configs.update(self._view_framings())
        return configs or None


@dataclass
class EnvSettings(PolicyEnvSettings):
    # Observations: state; rgb, rgbd, depth, segmentation or '+'-joined textures (rgb+depth+segmentation); or
    # pointcloud. A trained policy implies the mode its dataset was recorded in.
    obs_mode: str = setting("state", check=one_of(OBS_MODES))
    # The reward in next.reward and the reported returns: dense, normalized_dense, sparse or none.
    reward_mode: str = setting("dense", check=one_of(REWARD_MODES))
