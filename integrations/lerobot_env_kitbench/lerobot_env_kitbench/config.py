"""`--env.type=kitbench`: the LeRobot env config of kitbench's tasks.

Defined at module level (not inside a function) so that every process that unpickles it, lerobot's async
vector-env workers included, registers the same choice class on import.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

from lerobot.configs import FeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig

from kitbench.config.declare import leaves
from kitbench.env_settings import PolicyEnvSettings
from kitbench.envs.features import ENVIRONMENT_STATE, IMAGES, STATE, action_feature, observation_features
from kitbench.errors import check_choice
from kitbench.perturbations import Perturbations
from kitbench.registration import TASKS, make_env
from lerobot_env_kitbench.env import OBS_TYPES, OBSERVATION, obs_mode_of, register_lerobot_envs

# env observation key -> (dataset feature name, LeRobot feature type)
_STATE_KEYS = {"agent_pos": (STATE, FeatureType.STATE), "environment_state": (ENVIRONMENT_STATE, FeatureType.ENV)}


@lru_cache(maxsize=16)
def _env_features(
    task: str, control_mode: str, robot: str | None, obs_mode: str, points: int, camera_size: str | None
) -> tuple[dict, dict]:
    """The task's observation features in `obs_mode` (its cameras at `camera_size`) and its action feature, read
    off a state-only env: the env is the one place they are defined, and a state env needs no renderer."""
    sensors = PolicyEnvSettings(task=task, camera_size=camera_size).sensor_configs
    env = make_env(task, obs_mode="state", control_mode=control_mode, robot_uids=robot, sensor_configs=sensors)
    try:
        return observation_features(env, obs_mode, points), action_feature(env)
    finally:
        env.close()


# The task a config that names none runs (lerobot builds a default config for `--env.type=kitbench --help`).
DEFAULT_TASK = "LiftPegUpright-v1"


@EnvConfig.register_subclass("kitbench")
@dataclass
class KitbenchEnvConfig(PolicyEnvSettings, EnvConfig):
    """A kitbench task (`--env.task`, e.g. LiftPegUpright-v1) with LeRobot's observation names.

    `obs_type` "state" gives `agent_pos` (observation.state) and `environment_state`
    (observation.environment_state); "pixels_state" adds each camera's image (observation.images.<camera>) and
    parameters (observation.sensor_param.<camera>.*); any kitbench camera obs mode (rgbd, depth, segmentation,
    '+'-joined) or pointcloud adds what a dataset recorded in that mode holds, under the same names.
    `control_mode` must be the one the training dataset was recorded in.

    `task`, `robot`, `control_mode`, `pointcloud_points`, `camera_size` and `camera_view` are kitbench's own settings
    (`kitbench.env_settings`), declared, documented and checked there once. The comment above each field is its
    `--help` text (draccus reads comments, in this class and the ones it inherits from, not this docstring).
    """

    # Control steps per second (20: the tasks' control frequency).
    fps: int = 20
    # "state" (observation.state, observation.environment_state), "pixels_state" (adds the cameras' images), or
    # the obs mode the dataset was recorded in: rgbd, depth, segmentation, rgb+segmentation, ..., pointcloud.
    obs_type: str = "state"
    # The unit depth images were trained in: lerobot-train's --dataset.depth_output_unit ("mm", its default, or "m").
    depth_unit: str = "mm"
    # Steps before an episode is cut off; default: the task's own step limit for the robot (Fetch: 170).
    episode_length: int | None = None
    # How the env renders for lerobot's evaluation videos.
    render_mode: str = "rgb_array"
    # Robustness perturbations by name and level, e.g. '{"object_mass": 50, "action_delay": 1}' (see kitbench's
    # docs/evaluation.md); default: none.
    perturbations: dict = field(default_factory=dict)
    # Filled from the task's env (observation and action shapes); not meant to be set by hand.
    features: dict = field(default_factory=dict)
    # Filled with features: the env's observation keys mapped to the dataset's feature names.
    features_map: dict = field(default_factory=dict)

    def __post_init__(self):
        if self.task is None:
            self.task = DEFAULT_TASK
        PolicyEnvSettings.__post_init__(self)
        for name, leaf in leaves(PolicyEnvSettings).items():
            leaf.check(getattr(self, name))  # kitbench's own checks of its settings: one line each
        self.check_robot()
        self.check_camera_view()
        check_choice("obs_type", self.obs_type, OBS_TYPES)
        check_choice("depth_unit", self.depth_unit, ("mm", "m"))
        points = self.pointcloud_points
        Perturbations(self.perturbations)  # refuses unknown names and levels out of range here, in one line
        register_lerobot_envs()  # tasks registered after this package was imported get their gym ids too
        obs_mode = "state" if self.obs_type == "state" else obs_mode_of(self.obs_type)
        observations, action = _env_features(
            self.task, self.control_mode, self.robot, obs_mode, points, self.camera_size
        )
        self.features = {"action": PolicyFeature(type=FeatureType.ACTION, shape=tuple(action["shape"]))}
        self.features_map = {"action": "action"}
        for key, (name, kind) in _STATE_KEYS.items():
            self.features[key] = PolicyFeature(type=kind, shape=tuple(observations[name]["shape"]))
            self.features_map[key] = name
        for name, feature in observations.items():
            if name in (STATE, ENVIRONMENT_STATE):
                continue
            shape = tuple(feature["shape"])
            if name.startswith(IMAGES) and shape[-1] == 3:  # rgb: lerobot's own `pixels`
                key, kind = f"pixels/{name[len(IMAGES) :]}", FeatureType.VISUAL
            else:
                key = name[len(OBSERVATION) :]
                kind = FeatureType.VISUAL if name.startswith(IMAGES) else FeatureType.STATE
            self.features[key] = PolicyFeature(type=kind, shape=shape)
            self.features_map[key] = name

    @property
    def gym_kwargs(self) -> dict:
        kwargs = {"obs_type": self.obs_type, "control_mode": self.control_mode, "render_mode": self.render_mode}
        # the robot's own step limit (Fetch needs longer than the task's default), unless one is asked for
        steps = self.episode_length or TASKS[self.task].env_class.episode_steps(self.robot)
        if steps != TASKS[self.task].max_episode_steps:
            kwargs["max_episode_steps"] = steps
        if self.perturbations:
            kwargs["perturbations"] = dict(self.perturbations)
        if self.robot is not None:
            kwargs["robot_uids"] = self.robot
        if self.obs_type == "pointcloud":
            kwargs["pointcloud_points"] = self.pointcloud_points
        if self.sensor_configs is not None:
            kwargs["sensor_configs"] = self.sensor_configs
        if obs_mode_of(self.obs_type) not in ("state", "rgb"):
            kwargs["depth_unit"] = self.depth_unit
        return kwargs
