"""The simulated SO-101 on a kitbench task as a LeRobot `Robot` (`KitbenchSO101`), in the real follower's layout
(`lerobot/robots/so_follower`, `use_degrees`): `observation_features` and `action_features` are `<motor>.pos`
(`shoulder_pan` ... `wrist_roll` in degrees, `gripper` 0 closed .. 100 open) and, with rgb, the `front` and `wrist`
cameras' (height, width, 3) images; `send_action` takes goal positions and returns those sent (capped by
`max_relative_target` as the follower caps them, clipped to the joints' ranges).

What differs from the real follower: the goal positions drive the simulated arm in `pd_joint_pos` at the task's
control rate (each `send_action` steps the simulation at most once, when a control period has passed since the
last step, so lerobot's 30-60 fps loops run it in real time; `realtime=false`: one step per call), its arm joints
no faster than the real servos turn (`kitbench.teleop.limits.JointRateLimiter`, the limited steps counted); the
simulation advances only as actions arrive. Under lerobot-record (`recorder`) the scene is reset at LeRobot's
episode boundaries on the seed of the dataset's episode (`seed` + its index; a re-recorded episode meets its seed
again), held still through its reset phase, and each episode's arm waits at the start pose until the leader is
within `align` degrees of it; each saved episode's seed and success go to `meta/kitbench_episodes.jsonl`
(`episodes`). Elsewhere (lerobot-teleoperate, lerobot-rollout) the scene resets itself, on the next seed, once it
has run `settle_steps` past a success or reached its step limit, where a person resets a real station. A lerobot
command's Rerun view (`--display_data`) is laid out at connect (`kitbench.teleop.layout`: the cameras, each motor's
state beside the leader's goal); `viewer` opens a SAPIEN window on the scene. Nothing is
calibrated (the simulated joints read the real arm's calibrated degrees by construction) and there is no port,
torque or motor bus; the cameras are simulated at 128x128 (`camera_size`); the task's object state, which
kitbench's state datasets also record (`observation.environment_state`), is not an observation here, as no real
robot reports it.
"""

from __future__ import annotations

import logging
import sys
import time
from collections.abc import Callable
from functools import cached_property, lru_cache
from pathlib import Path

import numpy as np
from lerobot.robots import Robot
from lerobot.robots.utils import ensure_safe_goal_position
from lerobot.utils.errors import DeviceAlreadyConnectedError, DeviceNotConnectedError

from kitbench.env_settings import parse_size
from kitbench.envs.features import IMAGES, STATE, action_names, observation_features, observation_frame
from kitbench.envs.interface import KitbenchEnv
from kitbench.policies.joint_targets import joint_target_to_action
from kitbench.registration import make_env
from kitbench.teleop import layout
from kitbench.teleop.mapping import JointMapping
from kitbench.teleop.servo import ServoLimit
from kitbench.teleop.view import NoView, SapienView, View
from lerobot_robot_kitbench import recorder
from lerobot_robot_kitbench.config_kitbench_so101 import ROBOT, KitbenchSO101Config
from lerobot_robot_kitbench.episodes import EpisodeFile, Take

MODE = "pd_joint_pos"  # the follower takes absolute goal positions
# free: no recorder's episodes, scenes reset themselves; episode and reset: lerobot-record's phases
FREE, EPISODE, RESET = "free", "episode", "reset"
SAY_EVERY = 2.0  # seconds between the start-pose wait's lines
logger = logging.getLogger(__name__)


def _sensors(camera_size: str | None) -> dict | None:
    if camera_size is None:
        return None
    width, height = parse_size(camera_size)
    return {"width": width, "height": height}


@lru_cache(maxsize=16)
def _layout(task: str, obs_mode: str, camera_size: str | None) -> tuple[tuple[str, ...], dict, tuple[str, ...]]:
    """(the motors' names, each camera's image shape, the action's names), read off a state env: the env is the
    one place they are defined, and a state env needs no renderer."""
    env = make_env(task, obs_mode="state", control_mode=MODE, robot_uids=ROBOT, sensor_configs=_sensors(camera_size))
    try:
        features = observation_features(env, obs_mode)
        motors = tuple(features[STATE]["names"])
        cameras = {
            name[len(IMAGES) :]: tuple(feature["shape"])
            for name, feature in features.items()
            if name.startswith(IMAGES) and tuple(feature["shape"])[-1] == 3
        }
        return motors, cameras, tuple(action_names(env))
    finally:
        env.close()


class KitbenchSO101(Robot):
    """The simulated SO-101 (module docstring)."""

    config_class = KitbenchSO101Config
    name = "kitbench_so101"

    def __init__(self, config: KitbenchSO101Config):
        super().__init__(config)
        self.config = config
        self.env: KitbenchEnv | None = None
        self.obs = None
        self.seed = config.seed
        self.steps = 0  # control steps of the current scene
        self.first_success: int | None = None
        self.goal: dict[str, float] = {}  # the motors' goal positions, held between actions as the servos hold them
        self.due: float | None = None  # when the next control step is due (wall clock)
        self.scenes = 0  # scenes finished since connect
        self.phase = FREE
        self.fresh = False  # no control step since the scene's reset
        self.engaged = True  # the arm follows the goals (else it waits at the start pose for the leader)
        self.said = -SAY_EVERY  # when the start-pose wait last said which joints are off
        self.servo: ServoLimit | None = None  # the real servos' joint speeds (`kitbench.teleop.limits`)
        self.limited_steps = 0  # control steps since connect where a joint's speed limit held the arm back
        self.joints: JointMapping | None = None  # the leader's joints against the simulated arm's
        self.take: Take | None = None  # the lerobot-record episode in progress
        self.index = 0  # its dataset episode index
        self.file: EpisodeFile | None = None
        self.view: View = NoView()  # the SAPIEN viewer (`viewer`)

    # -- the layout ---------------------------------------------------------------------------------------------
    @cached_property
    def _names(self) -> tuple[tuple[str, ...], dict, tuple[str, ...]]:
        return _layout(self.config.task, self.config.obs_mode, self.config.camera_size)

    @property
    def motors(self) -> tuple[str, ...]:
        return self._names[0]

    @property
    def cameras(self) -> dict[str, tuple[int, int, int]]:
        """Each camera's image shape (height, width, 3), by the name lerobot records it under."""
        return dict(self._names[1])

    @property
    def observation_features(self) -> dict:
        return {**dict.fromkeys(self.motors, float), **self.cameras}

    @property
    def action_features(self) -> dict:
        return dict.fromkeys(self._names[2], float)

    # -- connection ---------------------------------------------------------------------------------------------
    @property
    def is_connected(self) -> bool:
        return self.env is not None

    def connect(self, calibrate: bool = True) -> None:
        if self.env is not None:
            raise DeviceAlreadyConnectedError(f"{self} is already connected")
        c = self.config
        self.view = SapienView() if c.viewer else NoView()
        self.view.open()
        self.env = make_env(
            c.task,
            obs_mode=c.obs_mode,
            control_mode=MODE,
            robot_uids=ROBOT,
            sensor_configs=_sensors(c.camera_size),
            max_episode_steps=c.episode_length,
            render_mode="rgb_array" if c.viewer else None,  # a viewer needs the scene rendered, as state has it not
        )
        self.scenes, self.due, self.phase, self.limited_steps = 0, None, FREE, 0
        self.servo = ServoLimit(self.env, joint_target_to_action)
        self.joints = JointMapping(self.env, joint_target_to_action)
        recorder.install(type(self))  # under lerobot-record, its episodes drive the scenes
        self._lay_out_rerun()
        self._new_scene(c.seed)
        logger.info("%s connected: %s, seed %d, %d Hz", self, c.task, c.seed, self.env.control_freq)

    def _lay_out_rerun(self) -> None:
        """Where a lerobot command shows its Rerun view (`--display_data=true`: a recording is open in this process),
        lay it out before its first frame: the cameras, and per motor its state beside the leader's goal."""
        if "rerun" not in sys.modules:
            return  # no view: lerobot imports rerun only to show one
        import rerun as rr

        if rr.get_global_data_recording() is not None:
            layout.send(self.motors, self.action_features, self.cameras)

    @property
    def is_calibrated(self) -> bool:
        return True  # the simulated joints read calibrated degrees by construction

    def calibrate(self) -> None:
        """Nothing to calibrate."""

    def configure(self) -> None:
        """Nothing to configure."""

    def disconnect(self) -> None:
        if self.env is None:
            raise DeviceNotConnectedError(f"{self} is not connected")
        if self.file is not None:
            self.file.settle()  # lerobot-record saved (or dropped) its last episode before letting go of the robot
        if self.limited_steps:
            logger.info("%s: the joints' speed limits held the arm back on %d steps", self, self.limited_steps)
        self.view.close()
        self.env.close()
        self.env = None

    # -- observations and actions --------------------------------------------------------------------------------
    def _env(self) -> KitbenchEnv:
        if self.env is None:
            raise DeviceNotConnectedError(f"{self} is not connected; run connect() first")
        return self.env

    def get_observation(self) -> dict:
        env = self._env()
        frame = observation_frame(env, self.obs)
        observation: dict = {name: float(v) for name, v in zip(self.motors, frame[STATE], strict=True)}
        for camera in self.cameras:
            observation[camera] = frame[IMAGES + camera]
        if self.take is not None:
            self.take.frames += 1
        return observation

    def send_action(self, action: dict) -> dict:
        env = self._env()
        wanted = {name: float(action[name]) for name in self.action_features if name in action}
        goal = dict(wanted)
        target = self.config.max_relative_target
        if target is not None and goal:
            present = dict(zip(self.motors, observation_frame(env, self.obs)[STATE], strict=True))
            goal = ensure_safe_goal_position({k: (v, float(present[k])) for k, v in goal.items()}, float(target))
        space = env.action_space
        names = list(self.action_features)
        for name, value in list(goal.items()):
            i = names.index(name)
            goal[name] = float(np.clip(value, space.low[i], space.high[i]))
            if self.take is not None and goal[name] != value:
                self.take.clipped += 1
        held = {name: self.goal[name] for name in goal}
        if self.phase == RESET:
            self._at_start_pose(env, wanted)  # the lines say which joints are off; the scene waits for the episode
            return held
        if not self.engaged and not self._at_start_pose(env, wanted):
            return held  # the arm waits at the start pose
        self.goal.update(goal)
        if self._step_due():
            self._step(env)
        return goal

    # -- lerobot-record's episodes (`recorder`) ------------------------------------------------------------------
    def begin_episode(self, index: int, root: Path, saved: Callable[[], int]) -> None:
        if self.file is None or self.file.root != root:
            self.file = EpisodeFile(root, saved)
        self.file.settle()
        env = self._env()
        seed = self.config.seed + index
        if not (self.fresh and self.seed == seed):
            self._new_scene(seed)
        self.phase, self.index, self.due = EPISODE, index, None
        self.engaged, self.said = not self.config.align, -SAY_EVERY
        self.take = Take(index, seed, {"control_mode": MODE, "obs_mode": self.config.obs_mode, **env.episode_config()})
        logger.info("%s: episode %d on seed %d", self, index, seed)

    def end_episode(self, ended: dict[str, str]) -> None:
        take, self.take = self.take, None
        if take is not None and self.file is not None:
            self.file.ended(take.info(ended))
            outcome = f"success at frame {take.first_success}" if take.first_success is not None else "no success"
            how = f"key {ended['key']}" if "key" in ended else ended["ended"]
            logger.info(
                "%s: episode %d (seed %d): %s, %d frames, ended by %s, %d values clipped, %d rate-limited steps",
                *(self, take.index, take.seed, outcome, take.frames, how, take.clipped, take.limited_steps),
            )

    def begin_reset(self, rerecord: bool) -> None:
        self.index += 0 if rerecord else 1
        self.phase, self.said = RESET, -SAY_EVERY
        self._new_scene(self.config.seed + self.index)
        self.engaged = False

    def _at_start_pose(self, env: KitbenchEnv, wanted: dict[str, float]) -> bool:
        """Whether the leader's arm joints (`wanted`, the goals it sent) are within `align` degrees of the simulated
        arm's; the first time they are, the arm follows from then on (`kitbench record`'s start-pose wait); until
        then a line every few seconds says which joints are off."""
        assert self.joints is not None, "connect() first"
        offsets = self.joints.offsets(env, {**self.goal, **wanted})
        off = {k: v for k, v in offsets.items() if abs(v) > self.config.align}
        if not off:
            if self.said >= 0:
                logger.info("%s: seed %d: the leader is at the start pose", self, self.seed)
                self.said = -SAY_EVERY
            self.engaged = self.phase != RESET
            return True
        now = time.monotonic()
        if now - self.said >= SAY_EVERY:
            far = ", ".join(f"{k} {v:+.0f}" for k, v in off.items())
            logger.info("%s: seed %d: the arm waits for the leader at its start pose (%s)", self, self.seed, far)
            self.said = now
        return False

    # -- the simulation ------------------------------------------------------------------------------------------
    def _step_due(self) -> bool:
        """Whether a control step is due: always without `realtime`, else once a control period has passed on the
        wall-clock schedule (a caller more than a period behind starts it afresh)."""
        if not self.config.realtime:
            return True
        period = self._env().control_timestep
        now = time.perf_counter()
        if self.due is not None and now < self.due:
            return False
        self.due = (now if self.due is None or now - self.due > period else self.due) + period
        return True

    def _step(self, env: KitbenchEnv) -> None:
        vector = self._servo(env, np.array([self.goal[name] for name in self.action_features], dtype=np.float32))
        self.obs, _, _, truncated, info = env.step(vector)
        self.fresh = False
        self.view.show(env, self.obs, vector)
        if info["success"] and self.first_success is None:
            self.first_success = self.steps
        self.steps += 1
        take = self.take
        if take is not None:
            if info["success"] and take.first_success is None:
                take.first_success = max(take.frames - 1, 0)
            take.steps += 1
            take.success_at_end = bool(info["success"])
        if self.phase != FREE:
            return  # lerobot-record's episodes end at its boundaries, not at the task's
        settled = self.first_success is not None and self.steps - 1 - self.first_success >= self.config.settle_steps
        if settled or truncated:
            outcome = "success" if self.first_success is not None else "no success"
            logger.info("%s: seed %d ended after %d steps (%s); next scene", self, self.seed, self.steps, outcome)
            self.scenes += 1
            self._new_scene(self.seed + 1)

    def _servo(self, env: KitbenchEnv, vector: np.ndarray) -> np.ndarray:
        """The goals as the servos follow them: each arm joint's target moves toward its goal no faster than the
        joint's speed limit (a step where one is held back is counted)."""
        assert self.servo is not None, "connect() first"
        before = self.servo.limited_steps
        vector = self.servo(env, vector)
        if self.servo.limited_steps > before:
            self.limited_steps += 1
            if self.take is not None:
                self.take.limited_steps += 1
        return vector

    def _new_scene(self, seed: int) -> None:
        """Reset on `seed`; the goals become where the arm now is (the servos hold their positions)."""
        env = self._env()
        self.obs, _ = env.reset(seed=seed)
        self.seed, self.steps, self.first_success, self.fresh = seed, 0, None, True
        self.view.episode(env, seed)
        self.view.show(env, self.obs, None)
        self.engaged = self.phase == FREE or not self.config.align
        assert self.servo is not None, "connect() first"
        self.servo.reset(env)
        state = observation_frame(env, self.obs)[STATE]
        motors = dict(zip(self.motors, state, strict=True))
        self.goal = {name: float(motors[name]) for name in self.action_features}
