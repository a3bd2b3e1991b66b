"""kitbench tasks as LeRobot environments (gym ids `gym_kitbench/<Task>`).

lerobot's eval loop reads observations named `agent_pos`, `environment_state` and `pixels` ({camera: HxWx3
uint8}) and success from `info["is_success"]`; it maps them to the dataset names kitbench's recorder writes
(`observation.state`, `observation.environment_state`, `observation.images.<camera>`), so a policy trained on
a kitbench dataset is evaluated on the same features. Every other observation a dataset stores (depth,
segmentation, a point cloud, the cameras' parameters) travels under its dataset name less `observation.`
(`images.<camera>_depth`, `pointcloud.xyz`, `sensor_param.<camera>.intrinsic_cv`, ...), which lerobot passes on as
`observation.<key>`, already in the layout `LeRobotDataset` returns (channels first, depth in `depth_unit`), since
lerobot converts only `pixels`; a policy reads those its input features name.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from kitbench.envs.features import ENVIRONMENT_STATE, IMAGES, STATE, as_loaded, observation_frame
from kitbench.envs.modes import IMAGE_OBS_MODES
from kitbench.envs.pointcloud import DEFAULT_POINTS, PointSampler
from kitbench.errors import check_choice
from kitbench.registration import TASKS, make_env

GYM_NAMESPACE = "gym_kitbench"
# "pixels_state" (LeRobot's name) is kitbench's rgb; the others are kitbench's obs modes by name.
OBS_TYPES = ("state", "pixels_state", *IMAGE_OBS_MODES)
OBSERVATION = "observation."
STATE_KEYS = {STATE: "agent_pos", ENVIRONMENT_STATE: "environment_state"}  # dataset name -> lerobot's env key


def obs_mode_of(obs_type: str) -> str:
    """The kitbench obs mode behind a LeRobot obs_type."""
    return "rgb" if obs_type == "pixels_state" else obs_type


class LeRobotKitbenchEnv(gym.Env):
    """One kitbench task with LeRobot's observation keys; `render()` gives the 512x512 third-person view."""

    # gymnasium declares `metadata` as an instance attribute; each env copies it with its own render_fps
    metadata: dict[str, Any] = {"render_modes": ["rgb_array"], "render_fps": 20}  # noqa: RUF012

    def __init__(
        self,
        task: str,
        obs_type: str = "state",
        control_mode: str = "pd_joint_delta_pos",
        render_mode: str | None = "rgb_array",
        perturbations: dict | None = None,
        robot_uids: str | None = None,
        pointcloud_points: int = DEFAULT_POINTS,
        depth_unit: str = "mm",
        sensor_configs: dict | None = None,
    ):
        check_choice("obs_type", obs_type, OBS_TYPES)
        check_choice("depth_unit", depth_unit, ("mm", "m"))
        obs_mode = "state_dict" if obs_type == "state" else obs_mode_of(obs_type)
        self._points = pointcloud_points
        self._depth_unit = depth_unit
        self._sampler = PointSampler(pointcloud_points, 0)
        self._env = make_env(
            task,
            obs_mode=obs_mode,
            control_mode=control_mode,
            render_mode=render_mode,
            perturbations=perturbations,
            robot_uids=robot_uids,
            sensor_configs=sensor_configs,
        ).unwrapped
        self.render_mode = render_mode
        self.metadata = {**self.metadata, "render_fps": self._env.sim_config.control_freq}
        self.action_space = self._env.action_space
        obs, _ = self._env.reset(seed=0)
        self.observation_space = self._space(self._convert(obs))

    @staticmethod
    def _space(obs: dict) -> spaces.Dict:
        out: dict[str, spaces.Space] = {}
        for key, value in obs.items():
            if key == "pixels":
                out[key] = spaces.Dict({c: spaces.Box(0, 255, im.shape, np.uint8) for c, im in value.items()})
            else:
                out[key] = spaces.Box(-np.inf, np.inf, value.shape, value.dtype)
        return spaces.Dict(out)

    def _convert(self, obs) -> dict:
        """The dataset's frame (`observation_frame`) under lerobot's env keys: rgb images under `pixels` as they
        are (lerobot converts them), everything else as `LeRobotDataset` returns it."""
        frame = observation_frame(self._env, obs, self._sampler)
        out: dict = {}
        pixels = {}
        rest = {}
        for name, value in frame.items():
            if name in STATE_KEYS:
                out[STATE_KEYS[name]] = value
            elif name.startswith(IMAGES) and value.shape[-1] == 3:
                pixels[name[len(IMAGES) :]] = value
            else:
                rest[name] = value
        if pixels:
            out["pixels"] = pixels
        for name, value in as_loaded(rest, self._depth_unit).items():
            out[name[len(OBSERVATION) :]] = value.astype(np.float32)
        return out

    @property
    def task(self) -> str:
        """The task id. lerobot-eval reads `task` and `task_description` from every sub-env; with async vector
        envs a missing attribute kills the worker (sync envs only warn)."""
        return self._env.task_id

    @property
    def task_description(self) -> str:
        return self._env.task_description()

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        obs, info = self._env.reset(seed=seed, options=options)
        # a seed's points are drawn as the recorder drew them (None: from the env's own draw of a seed)
        self._sampler = PointSampler(self._points, seed if seed is not None else int(self.np_random.integers(2**31)))
        return self._convert(obs), {**info, "is_success": bool(info["success"])}

    def step(self, action):
        obs, reward, terminated, truncated, info = self._env.step(action)
        return self._convert(obs), reward, terminated, truncated, {**info, "is_success": bool(info["success"])}

    def render(self):
        return self._env.render()

    def close(self):
        self._env.close()


def register_lerobot_envs() -> None:
    """`gym_kitbench/<Task>` for every kitbench task registered so far (safe to call again after more are)."""
    for name, entry in TASKS.items():
        gym_id = f"{GYM_NAMESPACE}/{name}"
        if gym_id not in gym.registry:
            gym.register(
                gym_id, entry_point=LeRobotKitbenchEnv, max_episode_steps=entry.max_episode_steps, kwargs={"task": name}
            )
