"""The gymnasium environment shared by kitbench's tabletop tasks.

A task subclass declares its robots, cameras and limits and implements five hooks: build its actors, place them
for a new episode, evaluate success, report its state fields and compute its dense reward. Everything else
(modes, the robot, control, stepping, observation and rendering) lives here once.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import sapien

from kitbench.control.controllers import CONTROL_MODES, make_controller
from kitbench.control.kinematics import PandaKinematics
from kitbench.envs.modes import IMAGE_OBS_MODES, OBS_MODES, REWARD_MODES, check_choice
from kitbench.envs.observations import flatten_state, pose7, space_for
from kitbench.robots.panda import READY_ARM_QPOS, ROBOTS, Panda, gripper_action_to_target
from kitbench.sim.cameras import Camera, CameraSpec
from kitbench.sim.scene import SimConfig, add_table_and_ground, create_scene

ROBOT_BASE = sapien.Pose([-0.615, 0.0, 0.0])


class TabletopEnv(gym.Env):
    """A Panda at a table, one task's objects, PhysX CPU, optional cameras."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 20}

    supported_robots: tuple[str, ...] = ("panda",)
    supported_reward_modes: tuple[str, ...] = REWARD_MODES
    max_episode_steps: int = 50
    max_dense_reward: float = 1.0
    default_qpos_noise: float = 0.02
    # Which of the task's state fields describe the world (objects, goals) rather than the robot: these form
    # LeRobot's `observation.environment_state`.
    environment_state_keys: tuple[str, ...] = ()

    def __init__(
        self,
        obs_mode: str = "state",
        control_mode: str = "pd_joint_delta_pos",
        reward_mode: str = "dense",
        robot_uids: str | None = None,
        render_mode: str | None = None,
        robot_init_qpos_noise: float | None = None,
        sim_config: SimConfig | None = None,
    ):
        robot_uids = robot_uids or self.supported_robots[0]
        check_choice("obs_mode", obs_mode, OBS_MODES)
        check_choice("control_mode", control_mode, CONTROL_MODES)
        check_choice("reward_mode", reward_mode, self.supported_reward_modes)
        check_choice("robot_uids", robot_uids, tuple(ROBOTS))
        if robot_uids not in self.supported_robots:
            raise ValueError(
                f"robot {robot_uids!r} is not supported by {type(self).__name__}; "
                f"valid choices: {', '.join(self.supported_robots)}"
            )
        check_choice("render_mode", render_mode, (None, *self.metadata["render_modes"]))
        self.obs_mode = obs_mode
        self.control_mode = control_mode
        self.reward_mode = reward_mode
        self.render_mode = render_mode
        self.robot_init_qpos_noise = self.default_qpos_noise if robot_init_qpos_noise is None else robot_init_qpos_noise
        self.sim_config = sim_config or SimConfig()
        self.metadata = {**self.metadata, "render_fps": self.sim_config.control_freq}
        self._renders = obs_mode in IMAGE_OBS_MODES or render_mode == "rgb_array"

        self.scene: sapien.Scene | None = None
        self.robot: Panda | None = None
        self._robot_spec = ROBOTS[robot_uids]
        self.controller = make_controller(control_mode, self._arm_limits(), PandaKinematics)
        self._cameras: dict[str, Camera] = {}
        self._human_camera: Camera | None = None
        self.action_space = self.controller.action_space
        self.elapsed_steps = 0
        self._last_info: dict = {}
        obs, _ = self.reset(seed=0)
        self.observation_space = space_for(obs)

    # -- task hooks ------------------------------------------------------------------------------
    def _load_task(self, scene: sapien.Scene, render: bool) -> None:
        """Build the task's actors into a fresh scene (visual shapes only when `render`)."""
        raise NotImplementedError

    def _initialize_episode(self, rng: np.random.Generator, options: dict) -> None:
        """Place the task's objects for a new episode."""
        raise NotImplementedError

    def evaluate(self) -> dict:
        raise NotImplementedError

    def _task_state(self, info: dict) -> dict[str, np.ndarray]:
        raise NotImplementedError

    def compute_dense_reward(self, info: dict) -> float:
        raise NotImplementedError

    def task_description(self) -> str:
        """The natural-language instruction for the current episode."""
        raise NotImplementedError

    def episode_config(self) -> dict:
        """What the current episode's seed chose beyond object poses (AssemblingKits: the kit and the shape), as
        plain values for dataset metadata and evaluation reports."""
        return {}

    def _sensor_cameras(self) -> list[CameraSpec]:
        return []

    def _render_camera(self) -> CameraSpec:
        return CameraSpec.looking_at("render_camera", [0.6, 0.7, 0.6], [0.0, 0.0, 0.35], 512, 512, 1.0)

    # -- gymnasium API ---------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        options = options or {}
        rng = self.np_random
        noise = rng.normal(0.0, self.robot_init_qpos_noise, 7) if self.robot_init_qpos_noise > 0 else 0.0
        arm_qpos = READY_ARM_QPOS + noise
        self._build_world()
        self.robot.reset(arm_qpos)
        self.controller.reset(arm_qpos)
        self._initialize_episode(rng, options)
        self.elapsed_steps = 0
        info = self.evaluate()
        self._last_info = info
        return self._observation(info), dict(info)

    def step(self, action):
        action = self._check_action(action)
        arm_qpos = self.robot.qpos()[:7]
        arm_targets = self.controller.arm_targets(action[:-1].astype(np.float64), arm_qpos)
        self.robot.set_targets(arm_targets, gripper_action_to_target(action[-1]))
        for _ in range(self.sim_config.substeps):
            self.scene.step()
        self.elapsed_steps += 1
        info = self.evaluate()
        self._last_info = info
        reward = self._reward(info)
        terminated = bool(info["success"])
        return self._observation(info), reward, terminated, False, dict(info)

    def render(self):
        if self._human_camera is None:
            raise RuntimeError(
                f"render() needs render_mode='rgb_array' at construction (got render_mode={self.render_mode!r})"
            )
        self.scene.update_render()
        self._human_camera.take_picture()
        return self._human_camera.rgb()

    def close(self):
        """Free the scene and everything in it (cameras, robot, actors)."""
        self._cameras = {}
        self._human_camera = None
        self.robot = None
        self.scene = None

    # -- internals --------------------------------------------------------------------------------
    def _build_world(self) -> None:
        """A fresh scene for every episode: table, robot, the task's objects and the cameras.

        PhysX keeps contact manifolds, friction anchors and pair orderings from earlier steps, so an episode
        that reused the previous episode's scene would not be bitwise reproducible from its seed. Building
        from cached parses takes a few milliseconds.
        """
        self.scene = create_scene(self.sim_config, render=self._renders)
        add_table_and_ground(self.scene, render=self._renders)
        self.robot = Panda(self.scene, self._robot_spec, ROBOT_BASE, render=self._renders)
        self._load_task(self.scene, self._renders)
        self._cameras, self._human_camera = {}, None
        if self.obs_mode in IMAGE_OBS_MODES:
            specs = [*self._sensor_cameras(), *self._robot_spec.cameras]
            self._cameras = {s.name: Camera(self.scene, s, self._mount(s)) for s in specs}
        if self.render_mode == "rgb_array":
            self._human_camera = Camera(self.scene, self._render_camera(), None)

    @staticmethod
    def _arm_limits() -> np.ndarray:
        from kitbench.control.kinematics import panda_model

        model = panda_model()
        return np.array([model.jnt_range[i] for i in range(7)])

    def _mount(self, spec: CameraSpec):
        if spec.mount is None:
            return None
        return self.robot.links[spec.mount].entity

    def _check_action(self, action) -> np.ndarray:
        a = np.asarray(action, dtype=np.float32)
        shape = self.action_space.shape
        if a.shape != shape:
            raise ValueError(f"action has shape {a.shape}; {self.control_mode} expects shape {shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"action contains NaN or inf: {a.tolist()}")
        return np.clip(a, self.action_space.low, self.action_space.high)

    def _reward(self, info: dict) -> float:
        if self.reward_mode == "sparse":
            return float(info["success"])
        if self.reward_mode == "none":
            return 0.0
        dense = self.compute_dense_reward(info)
        return dense / self.max_dense_reward if self.reward_mode == "normalized_dense" else dense

    def state_dict(self, info: dict) -> dict:
        """The nested state observation: `agent` (qpos, qvel) and `extra` (tcp_pose and the task's fields)."""
        extra = {"tcp_pose": pose7(self.robot.tcp_pose())}
        extra.update(self._task_state(info))
        return {
            "agent": {"qpos": self.robot.qpos().astype(np.float32), "qvel": self.robot.qvel().astype(np.float32)},
            "extra": extra,
        }

    def environment_state(self) -> np.ndarray:
        """Object and goal state as one float32 vector (see `environment_state_keys`)."""
        fields = self._task_state(self._last_info)
        return np.concatenate([np.asarray(fields[k], dtype=np.float32).reshape(-1) for k in self.environment_state_keys])

    @property
    def camera_names(self) -> tuple[str, ...]:
        """Cameras in image observations (empty unless obs_mode is rgb or rgbd)."""
        return tuple(self._cameras)

    def _observation(self, info: dict):
        if self.obs_mode == "none":
            return np.zeros(0, dtype=np.float32)
        state = self.state_dict(info)
        if self.obs_mode == "state":
            return flatten_state(state)
        if self.obs_mode == "state_dict":
            return state
        self.scene.update_render()
        for camera in self._cameras.values():
            camera.take_picture()
        sensor_data, sensor_param = {}, {}
        for name, camera in self._cameras.items():
            data = {"rgb": camera.rgb()}
            if self.obs_mode == "rgbd":
                data["depth"] = camera.depth()
            sensor_data[name] = data
            sensor_param[name] = camera.params()
        return {**state, "sensor_data": sensor_data, "sensor_param": sensor_param}

    @property
    def control_timestep(self) -> float:
        return 1.0 / self.sim_config.control_freq
