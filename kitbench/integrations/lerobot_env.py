"""kitbench tasks as LeRobot environments.

lerobot's eval loop reads observations named `agent_pos`, `environment_state` and `pixels` ({camera: HxWx3
uint8}) and success from `info["is_success"]`; it maps them to the dataset names the recorder writes
(`observation.state`, `observation.environment_state`, `observation.images.<camera>`), so a policy trained on
a kitbench dataset is evaluated on the same features.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from kitbench.recording.rollout import robot_state
from kitbench.registration import TASKS

OBS_TYPES = ("state", "pixels_state")
_ENV_STATE_DIMS = {"LiftPegUpright-v1": 7, "AssemblingKits-v1": 13}
_CAMERAS = {"LiftPegUpright-v1": ("base_camera",), "AssemblingKits-v1": ("base_camera", "hand_camera")}
_ARM_DIMS = {"pd_joint_delta_pos": 7, "pd_joint_pos": 7, "pd_ee_delta_pos": 3, "pd_ee_delta_pose": 6, "pd_ee_pose": 6}
CAMERA_SIZE = (128, 128)


class LeRobotKitbenchEnv(gym.Env):
    """One kitbench task with LeRobot's observation keys; `render()` gives the 512x512 third-person view."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 20}

    def __init__(self, task: str, obs_type: str = "state", control_mode: str = "pd_joint_delta_pos",
                 render_mode: str | None = "rgb_array"):
        if obs_type not in OBS_TYPES:
            raise ValueError(f"unknown obs_type {obs_type!r}; valid choices: {', '.join(OBS_TYPES)}")
        from kitbench.registration import make_env

        obs_mode = "rgb" if obs_type == "pixels_state" else "state_dict"
        self._env = make_env(task, obs_mode=obs_mode, control_mode=control_mode, render_mode=render_mode).unwrapped
        self.render_mode = render_mode
        self.metadata = {**self.metadata, "render_fps": self._env.sim_config.control_freq}
        self.action_space = self._env.action_space
        obs, _ = self._env.reset(seed=0)
        self.observation_space = self._space(self._convert(obs))

    @staticmethod
    def _space(obs: dict) -> spaces.Dict:
        out = {
            "agent_pos": spaces.Box(-np.inf, np.inf, obs["agent_pos"].shape, np.float32),
            "environment_state": spaces.Box(-np.inf, np.inf, obs["environment_state"].shape, np.float32),
        }
        if "pixels" in obs:
            out["pixels"] = spaces.Dict({c: spaces.Box(0, 255, im.shape, np.uint8) for c, im in obs["pixels"].items()})
        return spaces.Dict(out)

    def _convert(self, obs) -> dict:
        out = {"agent_pos": robot_state(self._env), "environment_state": self._env.environment_state()}
        if self._env.camera_names:
            out["pixels"] = {c: obs["sensor_data"][c]["rgb"] for c in self._env.camera_names}
        return out

    @property
    def task_description(self) -> str:
        return self._env.task_description()

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        obs, info = self._env.reset(seed=seed, options=options)
        return self._convert(obs), {**info, "is_success": bool(info["success"])}

    def step(self, action):
        obs, reward, terminated, truncated, info = self._env.step(action)
        return self._convert(obs), reward, terminated, truncated, {**info, "is_success": bool(info["success"])}

    def render(self):
        return self._env.render()

    def close(self):
        self._env.close()


def register_lerobot_envs() -> None:
    for name, entry in TASKS.items():
        gym_id = f"gym_kitbench/{name}"
        if gym_id not in gym.registry:
            gym.register(gym_id, entry_point="kitbench.integrations.lerobot_env:LeRobotKitbenchEnv",
                         max_episode_steps=entry.max_episode_steps, kwargs={"task": name})


def _config_class():
    """The EnvConfig subclass, defined lazily so importing kitbench never imports lerobot."""
    from lerobot.configs import FeatureType, PolicyFeature
    from lerobot.envs.configs import EnvConfig

    @EnvConfig.register_subclass("kitbench")
    @dataclass
    class KitbenchEnvConfig(EnvConfig):
        task: str | None = "LiftPegUpright-v1"
        fps: int = 20
        obs_type: str = "state"  # or "pixels_state" (camera images + state)
        control_mode: str = "pd_joint_delta_pos"
        episode_length: int | None = None  # default: the task's own limit
        render_mode: str = "rgb_array"
        features: dict = field(default_factory=dict)
        features_map: dict = field(default_factory=dict)

        def __post_init__(self):
            if self.task not in TASKS:
                raise ValueError(f"unknown task {self.task!r}; valid choices: {', '.join(TASKS)}")
            if self.obs_type not in OBS_TYPES:
                raise ValueError(f"unknown obs_type {self.obs_type!r}; valid choices: {', '.join(OBS_TYPES)}")
            if self.control_mode not in _ARM_DIMS:
                raise ValueError(f"unknown control_mode {self.control_mode!r}; valid choices: {', '.join(_ARM_DIMS)}")
            self.features = {
                "action": PolicyFeature(type=FeatureType.ACTION, shape=(_ARM_DIMS[self.control_mode] + 1,)),
                "agent_pos": PolicyFeature(type=FeatureType.STATE, shape=(8,)),
                "environment_state": PolicyFeature(type=FeatureType.ENV, shape=(_ENV_STATE_DIMS[self.task],)),
            }
            self.features_map = {"action": "action", "agent_pos": "observation.state",
                                 "environment_state": "observation.environment_state"}
            if self.obs_type == "pixels_state":
                for cam in _CAMERAS[self.task]:
                    self.features[f"pixels/{cam}"] = PolicyFeature(type=FeatureType.VISUAL, shape=(*CAMERA_SIZE, 3))
                    self.features_map[f"pixels/{cam}"] = f"observation.images.{cam}"

        @property
        def gym_kwargs(self) -> dict:
            kwargs = {"obs_type": self.obs_type, "control_mode": self.control_mode, "render_mode": self.render_mode}
            if self.episode_length is not None:
                kwargs["max_episode_steps"] = self.episode_length
            return kwargs

    return KitbenchEnvConfig


def __getattr__(name):
    if name == "KitbenchEnvConfig":
        cls = _config_class()
        globals()[name] = cls
        return cls
    raise AttributeError(name)
