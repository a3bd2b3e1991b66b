"""`KitbenchEnv`: what code outside `kitbench.envs` may ask of a kitbench env beyond gymnasium's API, typed.

`kitbench.registration.make_env` returns one; `as_kitbench(env)` makes one of any env whose innermost env is a
kitbench task (a plain `gym.make("kitbench/...")`). Policies, the recorder, the evaluation and the plugin read the
task, the modes, the robot and its controller through it, never through `env.unwrapped`, so what the env offers
the rest of kitbench is this one list.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

if TYPE_CHECKING:
    import sapien

    from kitbench.control.controllers import Controller
    from kitbench.envs.grasp import GraspHistory
    from kitbench.envs.tabletop import TabletopEnv
    from kitbench.robots import Robot, RobotSpec
    from kitbench.sim.cameras import CameraSpec
    from kitbench.sim.scene import SimConfig


class KitbenchEnv(gym.Wrapper):
    """A kitbench task env (any gymnasium wrappers around it kept), with the task, the robot and its controller."""

    def __init__(self, env: gym.Env):
        super().__init__(env)
        self._core: TabletopEnv = env.unwrapped  # type: ignore[assignment]

    @property  # type: ignore[misc]  # read only: nothing outside the env sets it
    def action_space(self) -> spaces.Box:  # type: ignore[override]  # every kitbench action space is a box
        return self.env.action_space  # type: ignore[return-value]

    # -- the task --------------------------------------------------------------------------------
    @property
    def task_id(self) -> str:
        return self._core.task_id

    def task_description(self) -> str:
        return self._core.task_description()

    def episode_config(self) -> dict:
        return self._core.episode_config()

    @property
    def success_criteria(self) -> tuple[str, ...]:
        return self._core.success_criteria

    @property
    def failure_categories(self) -> tuple[str, ...]:
        return self._core.failure_categories

    def failure_category(self, info: dict, grasp: GraspHistory) -> str | None:
        return self._core.failure_category(info, grasp)

    @property
    def target_object(self) -> sapien.Entity:
        return self._core.target_object

    def environment_state_names(self) -> list[str]:
        return self._core.environment_state_names()

    def tracked_frames(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        return self._core.tracked_frames()

    def has_expert(self) -> bool:
        return self._core.has_expert()

    def make_expert(self, options: dict[str, Any] | None = None) -> Any:
        return self._core.make_expert(options)

    @property
    def scene(self) -> sapien.Scene:
        return self._core.scene

    # -- modes and timing ------------------------------------------------------------------------
    @property
    def control_mode(self) -> str:
        return self._core.control_mode

    @property
    def obs_mode(self) -> str:
        return self._core.obs_mode

    @property
    def sim_config(self) -> SimConfig:
        return self._core.sim_config

    @property
    def control_timestep(self) -> float:
        return self._core.control_timestep

    @property
    def control_freq(self) -> int:
        return self._core.sim_config.control_freq

    # -- the robot and its controller ------------------------------------------------------------
    @property
    def robot_uid(self) -> str:
        return self._core.robot_uid

    @property
    def robot_spec(self) -> RobotSpec:
        return self._core.robot_spec

    @property
    def robot(self) -> Robot:
        return self._core.robot

    @property
    def controller(self) -> Controller:
        return self._core.controller

    def action_to_sim(self, action: np.ndarray) -> np.ndarray:
        """An action in the robot's units (the action space's) to the simulation's (radians, gripper -1..1)."""
        return self._core.action_to_sim(action)

    def action_from_sim(self, action: np.ndarray) -> np.ndarray:
        """An action in the simulation's units to the robot's (the action space's)."""
        return self._core.action_from_sim(action)

    def arm_action_scale(self) -> np.ndarray:
        """Action units per simulation unit of each arm entry (`TabletopEnv.arm_action_scale`)."""
        return self._core.arm_action_scale()

    # -- cameras ---------------------------------------------------------------------------------
    @property
    def camera_names(self) -> tuple[str, ...]:
        return self._core.camera_names

    def camera_specs(self) -> tuple[CameraSpec, ...]:
        return self._core.camera_specs()

    @property
    def camera_textures(self) -> frozenset[str]:
        return self._core.camera_textures

    @property
    def segmentation_id_map(self) -> dict[int, str]:
        return self._core.segmentation_id_map


def as_kitbench(env: gym.Env) -> KitbenchEnv:
    """`env` as a `KitbenchEnv` (itself when it is one)."""
    return env if isinstance(env, KitbenchEnv) else KitbenchEnv(env)
