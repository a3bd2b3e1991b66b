"""The gymnasium environment shared by kitbench's tabletop tasks, and the hooks a task implements.

A task is one module (see `kitbench/tasks/`): a subclass of `TabletopEnv` registered with
`@register_env("<Name>-v1", max_episode_steps=N)`. Everything else (modes, the robot, control, stepping,
observations, rendering) lives here once, and everything outside the task (recording, evaluation, policies,
the LeRobot plugin) asks the task through the public hooks below, never by its name.

Hooks the base calls while building and stepping (protected, as in ManiSkill): `_load_task`,
`_initialize_episode`, `_render_camera`, and the class attribute `sensor_cameras`. Hooks the rest of kitbench calls
(public): `evaluate`, `task_state`, `compute_dense_reward`, `task_description`, `target_object`, `failure_category`,
`tracked_frames`, `episode_config`, `make_expert`, `segmentation_names`, `observation_cameras`, and the class attributes
`success_criteria`, `failure_categories`, `environment_state_keys`, `report_groups`, `camera_views`.
"""

from __future__ import annotations

import abc
import copy
import functools
import importlib
from collections.abc import Mapping
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
import sapien
from gymnasium import spaces

from kitbench.control.controllers import CONTROL_MODES, JOINTS, make_controller
from kitbench.control.kinematics import ArmKinematics, arm_joint_limits
from kitbench.envs.grasp import GraspHistory
from kitbench.envs.modes import IMAGE_OBS_MODES, OBS_MODES, POINTCLOUD, REWARD_MODES, camera_textures
from kitbench.envs.observations import flatten_state, pose7, space_for
from kitbench.envs.physics_watch import PhysicsWatch
from kitbench.envs.pointcloud import fuse_cameras
from kitbench.envs.segmentation import SEGMENTATION_FIXED, segmentation_lut
from kitbench.errors import KitbenchError, check_choice, check_vector
from kitbench.perturbations import Perturbations
from kitbench.robots import ROBOTS, Robot, RobotSpec
from kitbench.robots.robot import GROUND_FREE_BIT
from kitbench.sim.cameras import Camera, CameraSpec, check_sensor_configs, configured
from kitbench.sim.scene import SimConfig, add_table_and_ground, create_scene

POSE_NAMES = ("x", "y", "z", "qw", "qx", "qy", "qz")
# Points farther than this along their camera's viewing axis leave the point cloud (w = 0). Measured at reset
# (seed 0): the table's pixels lie within 1.27 m of every camera of both tasks (LiftPegUpright's base camera:
# 0.43-1.27 m; the robot and the objects within 0.86 m) and the floor's from 1.53 m on (out to 7.6 m): 1.5 m keeps
# the workspace and drops the floor.
DEFAULT_POINTCLOUD_RANGE = 1.5


class TabletopEnv(gym.Env, abc.ABC):
    """A robot at a table, one task's objects, PhysX CPU, optional cameras."""

    # gymnasium declares `metadata` as an instance attribute; each env copies it with its own render_fps
    metadata: dict[str, Any] = {"render_modes": ["rgb_array"], "render_fps": 20}  # noqa: RUF012

    # Set by @register_env: the task's id ("LiftPegUpright-v1") and its step limit.
    task_id: ClassVar[str]
    max_episode_steps: ClassVar[int]

    supported_robots: ClassVar[tuple[str, ...]] = ("panda",)
    supported_reward_modes: ClassVar[tuple[str, ...]] = REWARD_MODES
    max_dense_reward: ClassVar[float] = 1.0
    default_qpos_noise: ClassVar[float] = 0.02
    # Which of the task's state fields describe the world (objects, goals) rather than the robot: these form
    # LeRobot's `observation.environment_state`.
    environment_state_keys: ClassVar[tuple[str, ...]] = ()
    # Boolean keys of `evaluate()` whose conjunction is success: reports give each one's rate.
    success_criteria: ClassVar[tuple[str, ...]] = ()
    # Every value `failure_category` can return, in the order of the task's stages (reports list them so).
    # Default: one "not_<criterion>" per success criterion.
    failure_categories: ClassVar[tuple[str, ...]] = ()
    # (id key, name key) of `episode_config()` by which reports break success down, e.g. per shape; None: none.
    report_groups: ClassVar[tuple[str, str] | None] = None
    # Step limits of robots that need longer than the task's own (`max_episode_steps`) to do it: kitbench's
    # `make_env` (record, eval, the LeRobot plugin) applies them; with gym.make pass max_episode_steps yourself.
    robot_max_episode_steps: ClassVar[dict[str, int]] = {}
    # Whether `_load_task` builds the task's object to `object_scale` (and `evaluate` measures it as built): the
    # `object_scale` perturbation is refused by tasks that do not.
    supports_object_scale: ClassVar[bool] = False
    # The task's own observation cameras (the robot adds its own): what image policies see.
    sensor_cameras: ClassVar[tuple[CameraSpec, ...]] = ()
    # Other framings of the observation cameras, by name, that a recording may choose (`camera_view`): ManiSkill
    # `sensor_configs` entries, {camera: {"pose": (x, y, z, qw, qx, qy, qz), "fov": radians}}, of the task's own
    # cameras or of a robot's (the SO-101's `front`); an env takes the entries of the cameras it has.
    camera_views: ClassVar[dict[str, dict[str, dict[str, Any]]]] = {}
    # The task's scripted expert: its class, or "module:Class" (as gymnasium's entry points), which keeps the
    # planner's module, which needs the task's geometry, from being imported by the task's own module; or a dict
    # of them by robot uid, for a task whose robots move too differently to share one.
    expert: ClassVar[str | type | dict[str, str | type] | None] = None
    # The bodies `step` checks for a diverged simulation, collected at the first step in each scene.
    _watched: PhysicsWatch | None = None

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        if cls.success_criteria and not cls.failure_categories:
            cls.failure_categories = tuple(f"not_{c}" for c in cls.success_criteria)

    def __init__(
        self,
        obs_mode: str = "state",
        control_mode: str = "pd_joint_delta_pos",
        reward_mode: str = "dense",
        robot_uids: str | None = None,
        render_mode: str | None = None,
        robot_init_qpos_noise: float | None = None,
        sim_config: SimConfig | None = None,
        perturbations: Mapping[str, float] | None = None,
        pointcloud_range: float = DEFAULT_POINTCLOUD_RANGE,
        sensor_configs: Mapping[str, Any] | None = None,
    ):
        """`pointcloud_range`: in obs_mode pointcloud, the depth (m, along each camera's viewing axis) beyond which
        a point is dropped from the cloud (its w set to 0). `sensor_configs`: the observation cameras' settings
        as ManiSkill takes them: `{"width": 64, "height": 64}` sizes every camera (each keeps its field of view);
        per camera, `{"base_camera": {"width": 64, "height": 64, "fov": 0.8, "pose": (x, y, z, qw, qx, qy, qz)}}`."""
        robot_uids = robot_uids or self.supported_robots[0]
        check_choice("obs_mode", obs_mode, OBS_MODES)
        check_choice("control_mode", control_mode, CONTROL_MODES)
        check_choice("reward_mode", reward_mode, self.supported_reward_modes)
        check_choice("robot_uids", robot_uids, tuple(ROBOTS))
        if robot_uids not in self.supported_robots:
            raise KitbenchError(
                f"robot {robot_uids!r} is not supported by {type(self).__name__}; "
                f"valid choices: {', '.join(self.supported_robots)}"
            )
        check_choice("render_mode", render_mode, (None, *self.metadata["render_modes"]))
        if isinstance(pointcloud_range, bool) or not (
            isinstance(pointcloud_range, int | float | np.integer | np.floating) and 0 < pointcloud_range < np.inf
        ):
            raise KitbenchError(f"pointcloud_range must be a positive number of metres, got {pointcloud_range!r}")
        self.pointcloud_range = float(pointcloud_range)
        self._robot_spec = ROBOTS[robot_uids]
        self.sensor_configs = check_sensor_configs(
            sensor_configs, [s.name for s in self._cameras_with(self._robot_spec)]
        )
        self._textures = camera_textures(obs_mode)
        self.obs_mode = obs_mode
        self.control_mode = control_mode
        self.reward_mode = reward_mode
        self.render_mode = render_mode
        self.robot_init_qpos_noise = self.default_qpos_noise if robot_init_qpos_noise is None else robot_init_qpos_noise
        self.sim_config = sim_config or SimConfig()
        self.metadata = {**self.metadata, "render_fps": self.sim_config.control_freq}
        self._renders = obs_mode in IMAGE_OBS_MODES or render_mode == "rgb_array"

        # The scene and robot exist from the first reset (below) until close().
        self.scene: sapien.Scene
        self.robot: Robot
        self.controller = make_controller(
            control_mode,
            self._arm_limits(),
            functools.partial(ArmKinematics, self._robot_spec),
            self._robot_spec.ee_position_bound,
        )
        self._cameras: dict[str, Camera] = {}
        self._human_camera: Camera | None = None
        self._segmentation_lut: np.ndarray | None = None  # per_scene_id -> stable id, for the current scene
        self._segmentation_names: tuple[str, ...] = ()
        self.action_space: spaces.Box = self._action_space()
        self.elapsed_steps = 0
        # Robustness perturbations (kitbench.perturbations), applied at the hooks below; their draws derive from
        # each episode's seed (reset(seed=None) draws a key from this generator, reseeded by every seed).
        self.perturbations = Perturbations(perturbations)
        self.perturbations.check(self)
        self._perturbation_keys = np.random.default_rng()
        obs, _ = self.reset(seed=0)
        self.observation_space = space_for(obs)

    @property
    def segmentation_id_map(self) -> dict[int, str]:
        """The stable id of every label a segmentation can hold, to its name: 0 background (nothing), the ground,
        the table, the robot's links in its model's order, then the task's `segmentation_names`. The same for
        every episode of this env (robot and task), whatever the episode builds."""
        if not self._segmentation_names:
            links = tuple(link.name for link in self.robot.articulation.links)
            self._segmentation_names = (*SEGMENTATION_FIXED, *links, *self.segmentation_names())
        return dict(enumerate(self._segmentation_names))

    # -- task hooks: building and stepping (called by this class) ------------------------------
    @abc.abstractmethod
    def _load_task(self, scene: sapien.Scene, render: bool) -> None:
        """Build the task's actors into a fresh scene (visual shapes only when `render`): every episode gets a
        new scene so that it is reproducible from its seed alone."""

    @abc.abstractmethod
    def _initialize_episode(self, rng: np.random.Generator, options: dict) -> None:
        """Place the task's objects for a new episode, drawing only from `rng` (the episode's seed)."""

    def _render_camera(self) -> CameraSpec:
        """The third-person camera of `render()` (videos): framed on the task's workspace."""
        return CameraSpec.looking_at("render_camera", [0.6, 0.7, 0.6], [0.0, 0.0, 0.35], 512, 512, 1.0)

    # -- task hooks: what the rest of kitbench asks the task --------------------------------------
    @abc.abstractmethod
    def evaluate(self) -> dict:
        """The task's measurements of the current state: `success`, every name in `success_criteria` (bool)
        and the errors behind them. Returned as `info` by reset and step, and scored by reports."""

    @abc.abstractmethod
    def task_state(self) -> dict[str, np.ndarray]:
        """The task's state fields (object poses, goals, ...), float32 arrays: they extend the state
        observation under `extra`, and those in `environment_state_keys` form LeRobot's environment state."""

    @abc.abstractmethod
    def compute_dense_reward(self, info: dict) -> float:
        """A shaped reward in [0, max_dense_reward] that reaches the maximum on success."""

    @abc.abstractmethod
    def task_description(self) -> str:
        """The natural-language instruction for the current episode (LeRobot's per-episode `task`)."""

    @property
    @abc.abstractmethod
    def target_object(self) -> sapien.Entity:
        """The actor the task is about: evaluation follows whether the robot holds it, logs follow its pose."""

    def failure_category(self, info: dict, grasp: GraspHistory) -> str | None:
        """Why an episode that ended in state `info` failed (one of `failure_categories`; None on success),
        judged from the earliest stage that went wrong. Default: the first criterion not met."""
        if info["success"]:
            return None
        for name in self.success_criteria:
            if not info[name]:
                return f"not_{name}"
        return self.failure_categories[-1] if self.failure_categories else "failed"

    def tracked_frames(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """World poses (position, wxyz quaternion) by frame name that logs show beside the robot's links:
        the target object by default; tasks add goals and fixtures."""
        pose = self.target_object.pose
        return {self.target_object.name: (pose.p, pose.q)}

    def segmentation_names(self) -> tuple[str, ...]:
        """The names of every actor the task may build, in a fixed order: their segmentation ids follow the
        robot's links' (`segmentation_id_map`). An obs mode with segmentation refuses a scene that shows an actor
        missing here."""
        return ()

    def episode_config(self) -> dict:
        """What the current episode's seed chose beyond object poses (AssemblingKits: the kit and the shape), as
        plain values for dataset metadata and evaluation reports."""
        return {}

    def make_expert(self, options: dict[str, Any] | None = None) -> Any:
        """The task's scripted expert for this env (planning `pd_joint_pos` targets: `reset(obs, info)`,
        `act(obs)`, `phase`, `tcp_target`), built from `expert` with its config's fields in `options` replaced;
        None when the task has none."""
        expert = type(self).expert_class(self.robot_uid)
        return None if expert is None else expert(self, expert.configured(self.robot_uid, options))

    @classmethod
    def expert_class(cls, robot_uid: str | None = None) -> Any:
        """The class of the task's expert for `robot_uid` (None: the task's default robot), imported from
        `expert`; None when the task has none. Lets a recipe be checked against the expert before an env exists."""
        entry = cls.expert
        if isinstance(entry, dict):  # one expert per robot
            robot = robot_uid or cls.supported_robots[0]
            if robot not in entry:
                raise KitbenchError(
                    f"task {cls.task_id} has no expert for robot {robot}; robots with one: {', '.join(entry)}"
                )
            entry = entry[robot]
        if isinstance(entry, str):
            module, _, name = entry.partition(":")
            entry = getattr(importlib.import_module(module), name)
        return entry

    @classmethod
    def episode_steps(cls, robot_uid: str | None = None) -> int:
        """The step limit of an episode with `robot_uid` (None: the task's default robot)."""
        robot = robot_uid or cls.supported_robots[0]
        return cls.robot_max_episode_steps.get(robot, cls.max_episode_steps)

    @classmethod
    def variant_description(cls, robot_uid: str) -> str | None:
        """How the task is built for `robot_uid` where that differs from its reference build (a dataset's card says
        it), in a phrase; None where it does not."""
        return None

    @classmethod
    def has_expert(cls) -> bool:
        return cls.expert is not None

    @property
    def object_scale(self) -> float:
        """The factor a task that `supports_object_scale` builds its object to (1 unless perturbed)."""
        return self.perturbations.object_scale()

    # -- gymnasium API ---------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        options = options or {}
        rng = self.np_random
        if self.perturbations:
            if seed is not None:
                self._perturbation_keys = np.random.default_rng(seed)
            self.perturbations.start_episode(seed if seed is not None else int(self._perturbation_keys.integers(2**62)))
        ready = np.asarray(self._robot_spec.ready_arm_qpos)
        noise = rng.normal(0.0, self.robot_init_qpos_noise, len(ready)) if self.robot_init_qpos_noise > 0 else 0.0
        arm_qpos = self.perturbations.initial_qpos(ready + noise)
        if "arm_qpos" in options:  # a given start (another simulator's): the seed's draws are still made
            arm_qpos = check_vector("options['arm_qpos']", options["arm_qpos"], len(ready))
        self._build_world()
        self.robot.reset(arm_qpos)
        self.controller.reset(arm_qpos)
        self._initialize_episode(rng, options)
        self.perturbations.objects(self)
        self.elapsed_steps = 0
        info = self.evaluate()
        obs = self._observation(info)
        self._last_finite = (obs, info)
        return obs, dict(info)

    def step(self, action):
        """One control step. If the physics diverges (a NaN, infinite or absurdly fast body, see
        `MAX_BODY_SPEED`), the episode ends instead: truncated, reward 0, not a success, the last finite
        observation and info, and `info["physics_error"]` saying which body went wrong and how."""
        executed = self.perturbations.action(self._check_action(action), self)
        if executed is not None:  # None: a delayed action has not arrived yet, the drives keep their targets
            self._apply(executed)
        for _ in range(self.sim_config.substeps):
            self.scene.step()
        self.elapsed_steps += 1
        fault = self._physics_fault()
        if fault is not None:
            # copies: the previous step returned these same objects, and callers may keep or modify them
            obs, info = copy.deepcopy(self._last_finite)
            info.update(success=False, physics_error=f"PhysX diverged at step {self.elapsed_steps}: {fault}")
            return obs, 0.0, False, True, info
        info = self.evaluate()
        reward = self._reward(info)
        terminated = bool(info["success"])
        obs = self._observation(info)
        self._last_finite = (obs, info)
        return obs, reward, terminated, False, dict(info)

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
        self._watched = None
        # dropping the references lets PhysX and the renderer free the scene; a closed env runs again after reset
        self.robot = None  # type: ignore[assignment]  # typed for the open env, which always has one
        self.scene = None

    # -- internals --------------------------------------------------------------------------------
    def _build_world(self) -> None:
        """A fresh scene for every episode: table, robot, the task's objects and the cameras.

        PhysX keeps contact manifolds, friction anchors and pair orderings from earlier steps, so an episode
        that reused the previous episode's scene would not be bitwise reproducible from its seed. Building
        from cached parses takes a few milliseconds.
        """
        self.scene = create_scene(self.sim_config, render=self._renders)
        spec = self._robot_spec
        add_table_and_ground(
            self.scene,
            render=self._renders,
            near_edge=None if spec.table_clearance is None else spec.base_pose[0][0] + spec.table_clearance,
            shared_bits=GROUND_FREE_BIT if spec.ground_free_links else 0,
        )
        if self._renders:
            self.perturbations.lighting(self.scene)
        base = self.perturbations.robot_base(sapien.Pose(*self._robot_spec.base_pose))
        self.robot = Robot(self.scene, self._robot_spec, base, render=self._renders)
        self._load_task(self.scene, self._renders)
        self._cameras, self._human_camera = {}, None
        self._segmentation_lut = None
        if self.obs_mode in IMAGE_OBS_MODES:
            specs = [self.perturbations.camera(s) for s in self.camera_specs()]
            self._cameras = {s.name: Camera(self.scene, s, self._mount(s)) for s in specs}
        if self.render_mode == "rgb_array":
            self._human_camera = Camera(self.scene, self._render_camera(), None)
        # The bodies `_physics_fault` watches, collected at the first step: a task may add bodies while it
        # initialises the episode (AssemblingKits builds its kit there).
        self._watched = None

    def _physics_fault(self) -> str | None:
        """What is wrong with the simulation after a step (None when nothing is): `PhysicsWatch.fault`."""
        if self._watched is None:
            self._watched = PhysicsWatch(self.scene, self.robot)
        return self._watched.fault()

    def _arm_limits(self) -> np.ndarray:
        # a continuous joint (a wrist roll) gets +-2 pi: absolute targets beyond a turn mean nothing more
        return np.clip(arm_joint_limits(self._robot_spec), -2 * np.pi, 2 * np.pi)

    def _action_space(self) -> spaces.Box:
        """The controller's arm part and gripper, then the robot's body joint deltas and base velocities, in the
        robot's units."""
        spec = self._robot_spec
        controller = self.controller
        space = controller.physical_space if spec.units.expresses(self._joints) else controller.action_space
        arm_low, arm_high = spec.units.action_bounds(spec, self._joints, self._n_arm, space.low, space.high)
        low, high = spec.extra_action_bounds()
        return spaces.Box(np.concatenate([arm_low, low]), np.concatenate([arm_high, high]), dtype=np.float32)

    @property
    def _n_arm(self) -> int:
        """Entries of the action's arm part (before the gripper)."""
        return self.controller.physical_space.shape[0] - 1

    @property
    def _joints(self) -> bool:
        """Whether the mode's arm part is the arm's joints (which a robot's units may express)."""
        return self.controller.frame == JOINTS

    def action_to_sim(self, action: np.ndarray) -> np.ndarray:
        """An action as the action space has it (ManiSkill's form, `Controller.decode`, or the robot's units where
        they express the mode: `RobotSpec.units`) to the simulation's: the arm part in radians, metres and
        axis-angle vectors, the gripper a command from -1 (closed) to 1 (open)."""
        spec, joints, n = self._robot_spec, self._joints, self._n_arm
        out = np.array(spec.units.action_to_sim(spec, joints, n, action), dtype=np.float64)
        if not spec.units.expresses(joints):
            out[:n] = self.controller.decode(out[:n])
        out[n + 1 :] /= spec.extra_action_scale()
        return out

    def action_from_sim(self, action: np.ndarray) -> np.ndarray:
        """`action_to_sim`'s inverse: an action in the simulation's units to the action space's (unclipped)."""
        spec, joints, n = self._robot_spec, self._joints, self._n_arm
        out = np.array(action, dtype=np.float64)
        if not spec.units.expresses(joints):
            out[:n] = self.controller.encode(out[:n])
        out[n + 1 :] *= spec.extra_action_scale()
        return spec.units.action_from_sim(spec, joints, n, out).astype(np.asarray(action).dtype)

    def arm_action_scale(self) -> np.ndarray:
        """Action units per simulation unit of each arm entry (a joint's degrees, a normalised delta's 10 per rad
        or m): noise sized in simulation units is this much in the action."""
        spec, joints = self._robot_spec, self._joints
        if spec.units.expresses(joints):
            return np.full(self._n_arm, spec.units.joint_unit(joints))
        return self.controller.scale()

    def _apply(self, action: np.ndarray) -> None:
        """Send one checked action to the drives: arm, gripper, body joints, base (module `kitbench.robots.spec`)."""
        spec, robot = self._robot_spec, self.robot
        n_arm = self._n_arm
        action = self.action_to_sim(action)
        if spec.body_joints:
            self.controller.set_body(robot.body_qpos())  # a torso's height moves where the arm reaches
        arm_targets = self.controller.arm_targets(action[:n_arm].astype(np.float64), robot.arm_qpos())
        robot.set_targets(arm_targets, spec.gripper_target(action[n_arm]))
        extra = action[n_arm + 1 :].astype(np.float64)
        n_body = len(spec.body_joints)
        if n_body:
            limits = robot.body_limits
            robot.set_body_targets(np.clip(robot.body_targets() + extra[:n_body], limits[:, 0], limits[:, 1]))
        if spec.has_base:
            robot.set_base_velocity(extra[n_body], extra[n_body + 1], self.control_timestep)

    def _mount(self, spec: CameraSpec):
        if spec.mount is None:
            return None
        return self.robot.links[spec.mount].entity

    def _check_action(self, action) -> np.ndarray:
        a = np.asarray(action, dtype=np.float32)
        shape = self.action_space.shape
        if a.shape != shape:
            raise KitbenchError(f"action has shape {a.shape}; {self.control_mode} expects shape {shape}")
        if not np.all(np.isfinite(a)):
            raise KitbenchError(f"action contains NaN or inf: {a.tolist()}")
        return np.clip(a, self.action_space.low, self.action_space.high)

    def _reward(self, info: dict) -> float:
        if self.reward_mode == "sparse":
            return float(info["success"])
        if self.reward_mode == "none":
            return 0.0
        dense = self.compute_dense_reward(info)
        return dense / self.max_dense_reward if self.reward_mode == "normalized_dense" else dense

    def state_dict(self) -> dict:
        """The nested state observation: `agent` (qpos, qvel) and `extra` (tcp_pose and the task's fields)."""
        extra = {"tcp_pose": pose7(self.robot.tcp_pose())}
        if self._robot_spec.has_base:  # where a mobile base has driven to (world)
            extra["base_pose"] = pose7(self.robot.base_pose)
        extra.update(self.task_state())
        state = {
            "agent": {"qpos": self.robot.qpos().astype(np.float32), "qvel": self.robot.qvel().astype(np.float32)},
            "extra": extra,
        }
        if self.perturbations.changes_observations:
            return self.perturbations.observation(state, self.elapsed_steps)
        return state

    def robot_state(self) -> np.ndarray:
        """LeRobot's `observation.state`, named by `robot_state_names`: the arm's joint positions, the gripper
        opening (sum of the finger joints, metres), then any body joints and a mobile base's x, y, yaw: what a
        real robot reports of itself, no simulator-only quantities; in the robot's units (`RobotSpec.units`: the
        SO-101's degrees and jaw 0..100)."""
        # measured as the state observation is (with its noise, under an observation perturbation)
        q = self.state_dict()["agent"]["qpos"] if self.perturbations.changes_observations else self.robot.qpos()
        spec = self._robot_spec
        return spec.units.state(spec, self.robot.state_vector(q)).astype(np.float32)

    @property
    def robot_state_names(self) -> tuple[str, ...]:
        return self._robot_spec.state_names

    @property
    def robot_spec(self) -> RobotSpec:
        """The robot this env runs (its joints, action layout and cameras)."""
        return self._robot_spec

    def environment_state(self) -> np.ndarray:
        """Object and goal state as one float32 vector (see `environment_state_keys`)."""
        fields = self.state_dict()["extra"] if self.perturbations.changes_observations else self.task_state()
        return np.concatenate(
            [np.asarray(fields[k], dtype=np.float32).reshape(-1) for k in self.environment_state_keys]
        )

    def environment_state_names(self) -> list[str]:
        """One name per entry of `environment_state()`: `<field>.<x|...|qz>` for poses, `<field>.<i>` else."""
        fields = self.task_state()
        names: list[str] = []
        for key in self.environment_state_keys:
            size = int(np.asarray(fields[key]).size)
            if size == 7 and key.endswith("pose"):
                names += [f"{key}.{n}" for n in POSE_NAMES]
            elif size == 1:
                names.append(key)
            else:
                names += [f"{key}.{i}" for i in range(size)]
        return names

    def camera_specs(self) -> tuple[CameraSpec, ...]:
        """Every camera an image observation has (the task's, then the robot's), whatever this env's obs mode, at
        the size, field of view and pose `sensor_configs` asks."""
        return tuple(configured(spec, self.sensor_configs) for spec in self._cameras_with(self._robot_spec))

    @classmethod
    def _cameras_with(cls, robot: RobotSpec) -> tuple[CameraSpec, ...]:
        return (*(cls.sensor_cameras if robot.task_cameras else ()), *robot.cameras)

    @classmethod
    def observation_cameras(cls, robot_uid: str) -> tuple[str, ...]:
        """The observation cameras this task has with a robot (the task's, then the robot's), without an env."""
        return tuple(spec.name for spec in cls._cameras_with(ROBOTS[robot_uid]))

    @property
    def robot_uid(self) -> str:
        """The robot variant this env runs (LeRobot's `robot_type`)."""
        return self._robot_spec.uid

    @property
    def observes_images(self) -> bool:
        """Whether observations come from cameras (any obs mode in `IMAGE_OBS_MODES`)."""
        return self.obs_mode in IMAGE_OBS_MODES

    @property
    def camera_textures(self) -> frozenset[str]:
        """What this env's obs mode renders per camera: a subset of rgb, depth, segmentation."""
        return self._textures

    @property
    def camera_names(self) -> tuple[str, ...]:
        """Cameras in this env's observations (empty unless the obs mode renders them)."""
        return tuple(self._cameras)

    def _observation(self, info: dict):
        if self.obs_mode == "none":
            return np.zeros(0, dtype=np.float32)
        state = self.state_dict()
        if self.obs_mode == "state":
            return flatten_state(state)
        if self.obs_mode == "state_dict":
            return state
        self.scene.update_render()
        for camera in self._cameras.values():
            camera.take_picture()
        textures = self._textures
        sensor_data, sensor_param = {}, {}
        for name, camera in self._cameras.items():
            data = {}
            if "rgb" in textures:
                data["rgb"] = camera.rgb()
            if "depth" in textures:
                data["depth"] = camera.depth()
            if "segmentation" in textures:
                data["segmentation"] = self._segmentation(camera)
            sensor_data[name] = data
            sensor_param[name] = camera.params()
        if self.obs_mode == POINTCLOUD:
            return {**state, "pointcloud": self._pointcloud(sensor_data, sensor_param), "sensor_param": sensor_param}
        return {**state, "sensor_data": sensor_data, "sensor_param": sensor_param}

    def _segmentation(self, camera: Camera) -> np.ndarray:
        """(H, W, 1) uint16 stable ids (`segmentation_id_map`) of what each pixel sees; the scene's table is built
        at its first segmentation, once the task has built everything (AssemblingKits builds its kit while it
        initialises the episode)."""
        if self._segmentation_lut is None:
            self._segmentation_lut = segmentation_lut(self.scene, self.robot, self.segmentation_id_map, type(self))
        return self._segmentation_lut[camera.entity_ids()][..., None]

    def _pointcloud(self, sensor_data: dict, sensor_param: dict) -> dict[str, np.ndarray]:
        return fuse_cameras(self._cameras, sensor_data, sensor_param, self.pointcloud_range)

    @property
    def control_timestep(self) -> float:
        return 1.0 / self.sim_config.control_freq
