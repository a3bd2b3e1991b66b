"""kitbench tasks as LeRobot environments (gym ids `gym_kitbench/<Task>`).

lerobot's eval loop reads observations named `agent_pos`, `environment_state` and `pixels` ({camera: HxWx3
uint8}) and success from `info["is_success"]`; it maps them to the dataset names kitbench's recorder writes
(`observation.state`, `observation.environment_state`, `observation.images.<camera>`), so a policy trained on
a kitbench dataset is evaluated on the same features.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from kitbench.errors import check_choice
from kitbench.registration import TASKS, make_env

GYM_NAMESPACE = "gym_kitbench"
OBS_TYPES = ("state", "pixels_state")


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
    ):
        check_choice("obs_type", obs_type, OBS_TYPES)
        obs_mode = "rgb" if obs_type == "pixels_state" else "state_dict"
        self._env = make_env(
            task,
            obs_mode=obs_mode,
            control_mode=control_mode,
            render_mode=render_mode,
            perturbations=perturbations,
            robot_uids=robot_uids,
        ).unwrapped
        self.render_mode = render_mode
        self.metadata = {**self.metadata, "render_fps": self._env.sim_config.control_freq}
        self.action_space = self._env.action_space
        obs, _ = self._env.reset(seed=0)
        self.observation_space = self._space(self._convert(obs))

    @staticmethod
    def _space(obs: dict) -> spaces.Dict:
        out: dict[str, spaces.Space] = {
            "agent_pos": spaces.Box(-np.inf, np.inf, obs["agent_pos"].shape, np.float32),
            "environment_state": spaces.Box(-np.inf, np.inf, obs["environment_state"].shape, np.float32),
        }
        if "pixels" in obs:
            out["pixels"] = spaces.Dict({c: spaces.Box(0, 255, im.shape, np.uint8) for c, im in obs["pixels"].items()})
        return spaces.Dict(out)

    def _convert(self, obs) -> dict:
        out = {"agent_pos": self._env.robot_state(), "environment_state": self._env.environment_state()}
        if self._env.camera_names:
            out["pixels"] = {c: obs["sensor_data"][c]["rgb"] for c in self._env.camera_names}
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
