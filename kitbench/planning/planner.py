"""`PhasePlanner`: what every scripted expert shares, around the one thing each task supplies, its phase table.

An expert plans TCP paths, solves and times them (`ik.ArmIK.plan`, as fast as the Panda's joint limits allow,
`timing`) and plays the resulting steps phase by phase (`phases.PhaseSequencer`), planning each phase when it
starts. A task's expert subclasses `PhasePlanner` and implements its hooks: the config it is tuned by and the
transition table from one phase to the next (the actor it handles is the task's `target_object`).
"""

from __future__ import annotations

import dataclasses
from abc import ABC, abstractmethod
from collections.abc import Callable
from typing import Any, ClassVar

import numpy as np

from kitbench.control.controllers import JOINTS
from kitbench.control.kinematics import ArmKinematics
from kitbench.errors import KitbenchError
from kitbench.planning.ik import ArmIK, TimedPath
from kitbench.planning.phases import OPEN, PhaseSequencer, Step, hold
from kitbench.planning.poses import pose_matrix

# In pd_joint_delta_pos the target leads the measured joints by at most the action bound (0.1 rad), and the
# drives cover only part of a lead in one control step; a plan faster than that falls behind and the swing loses
# the peg; plans there use this fraction of the bound per step. Under ManiSkill's gains (docs/fidelity.md),
# LiftPegUpright seeds 0-39 with 100 steps: 0/40 at 0.6, 40/40 at 0.4 (median 62 steps, past the task's 50),
# 40/40 at 0.3 (median 73); AssemblingKits seeds 0-39 at 0.4: 40/40 (median 72 of 200).
MEASURED_DELTA_TRACKING = 0.4
# Each action's joint targets lead the plan by this share of the drives' lag (damping / stiffness times the plan's
# joint velocity): with ManiSkill's gains the Panda trails a swing by up to 0.19 rad, and the LiftPegUpright expert
# then set 45 of 100 pegs down at the wrong height; at 0.5: 100/100 (at 1.0 the overshoot re-grasped 5 of them).
DRIVE_LEAD = 0.5
# mixed into the episode seed for the expert's own random draws (`PhasePlanner.rng`)
EXPERT_STREAM = 0x6578_7074


def check_spread(name: str, spread: float, base: tuple[str, float] | None = None, zero_is: str = "0") -> None:
    """An expert option that spreads a setting over episodes (`drawn_within`) is a width, 0 or more; given `base`
    (the setting's name and value), no draw may fall below 0, which `zero_is` names in the error."""
    if not spread >= 0.0:
        raise KitbenchError(f"expert option {name} must be >= 0 (0: no spread), got {spread!r}")
    if base is not None and base[1] - spread < 0.0:
        raise KitbenchError(
            f"expert option {name}={spread!r} reaches below {zero_is}: it must be at most {base[0]} ({base[1]!r})"
        )


def drawn_within(rng: np.random.Generator, value: float, spread: float) -> float:
    """`value`, or with a `spread` a uniform draw within it of `value` (nothing drawn without one)."""
    return value + float(rng.uniform(-spread, spread)) if spread else value


class PhasePlanner(ABC):
    """Closed loop between phases, open loop within them; reads the simulated state from `env.unwrapped`.

    `act` returns a `pd_joint_pos` arm action (the arm's joint targets, then the gripper, -1 closed .. 1 open;
    no body or base entries) whatever the env's
    control mode: an env in another mode needs the target converted (`kitbench.policies.joint_targets`). In the joint
    delta modes the plans keep every joint step inside the +-0.1 rad action box (2 rad/s, below joints 5-7's
    2.61 rad/s): a clipped step would leave the joints out of step with one another.

    `phase` names the phase being played (one of the class's `phases`) and `tcp_target` is the 4x4 world TCP pose
    of the last action.
    `grasp_attempts` and `failure` (None, or why the expert gave up) let benchmarks sort failures.

    `config` (default `default_config()`) is a frozen dataclass of the expert's tunables; the base class reads
    its `speed_factor`, the fraction of the robot's joint velocity and acceleration limits plans may use, its
    `drive_lead` where it has one (`DRIVE_LEAD` otherwise), and its `ee_delta_tracking` where it has one (None
    otherwise: plans in the measured end-effector delta modes at the joint limits).
    """

    # Every phase name the expert plays, in the order an episode meets them, "failed" last (`_fail`): what
    # `kitbench record --noise-phases` may name, so a recipe's phases are checked before anything runs.
    phases: ClassVar[tuple[str, ...]] = ()

    def __init__(self, env, config=None):
        self.env = env.unwrapped
        self.cfg = config or self.robot_config(self.env.robot_uid)
        self.dt = self.env.control_timestep
        spec = self.env.robot_spec
        self.n_arm = len(spec.arm_joints)
        self.max_velocity = self.cfg.speed_factor * np.asarray(spec.arm_velocity_limits)
        self.max_acceleration = self.cfg.speed_factor * np.asarray(spec.arm_acceleration_limits)
        controller = self.env.controller
        if controller.frame == JOINTS and controller.delta:  # their actions move a joint at most this far per step
            fraction = 0.98 if controller.target_delta else MEASURED_DELTA_TRACKING
            step_limit = controller.physical_space.high[: self.n_arm].astype(np.float64) * fraction
            self.max_velocity = np.minimum(self.max_velocity, step_limit / self.dt)
        tracking = getattr(self.cfg, "ee_delta_tracking", None)
        if tracking is not None and not 0.0 < tracking <= 1.0:
            raise KitbenchError(
                f"expert option ee_delta_tracking must be within (0, 1] of the action bound a step (null: plans at "
                f"the joint limits), got {tracking!r}"
            )
        if controller.frame != JOINTS and controller.delta and not controller.target_delta and tracking is not None:
            # measured TCP deltas lead the hand by at most the action bound (0.1 m, 0.1 rad) a step, and the drives
            # cover part of it: each joint kept to that share of the bound a step, as in the joint-delta modes
            step_limit = tracking * float(np.max(controller.physical_space.high[: len(controller.tcp_names)]))
            self.max_velocity = np.minimum(self.max_velocity, step_limit / self.dt)
        kinematics = ArmKinematics(spec)
        kinematics.set_body(self.env.robot.body_qpos())
        self.ik = ArmIK(pose_matrix(self.env.robot.base_pose), kinematics)
        # a PD drive with no velocity target trails a joint moving at v by v * damping / stiffness
        self.lead = getattr(self.cfg, "drive_lead", DRIVE_LEAD) * spec.arm_damping / spec.arm_stiffness
        self.sequencer = PhaseSequencer(self.plan_next)
        self.reset()

    # -- hooks ----------------------------------------------------------------------------------------------------
    @classmethod
    @abstractmethod
    def default_config(cls):
        """The config used when none is given: each task's motion has its own tunables (and measured defaults)."""

    @classmethod
    def robot_config(cls, robot_uid: str):
        """The config used for `robot_uid` when none is given: `default_config()`, unless a planner tunes its
        motion per robot."""
        return cls.default_config()

    @classmethod
    def configured(cls, robot_uid: str, options: dict[str, Any] | None = None):
        """`robot_config(robot_uid)` with the fields named in `options` replaced (a recipe's or `--policy-option`'s
        expert settings, e.g. `close_steps=6`); an unknown field or a value of the wrong type is one line naming
        the valid fields."""
        config = cls.robot_config(robot_uid)
        if not options:
            return config
        fields = {f.name: f for f in dataclasses.fields(config)}
        for key, value in options.items():
            if key not in fields:
                raise KitbenchError(
                    f"unknown expert option {key!r} for {cls.__name__}; valid choices: {', '.join(fields)}"
                )
            current = getattr(config, key)
            if not _same_kind(current, value):
                raise KitbenchError(
                    f"expert option {key}={value!r} for {cls.__name__} must be {_kind_name(current)} "
                    f"like its default {current!r}"
                )
        floats = {k for k, v in options.items() if isinstance(getattr(config, k), float) and v is not None}
        return dataclasses.replace(config, **{k: float(v) if k in floats else v for k, v in options.items()})

    def target_actor(self):
        """The actor the expert manipulates: the grasp checks and the object pose measured between phases read
        it. By default the task's own `target_object`, so planner and evaluation follow the same actor."""
        return self.env.target_object

    @abstractmethod
    def plan_next(self, finished: str | None) -> list[Step]:
        """The transition table: the steps after phase `finished` (None at the start of an episode), planned from
        the simulated state now. This is where a task's expert closes the loop, e.g. retrying a missed grasp."""

    def on_reset(self) -> None:  # noqa: B027  (an optional hook: most experts keep no per-episode state)
        """Clear task-specific per-episode state and make the episode's draws from `rng`; runs at the end of every
        `reset` (nothing by default)."""

    # -- public API -----------------------------------------------------------------------------------------------
    def reset(self, obs=None, info=None, seed: int | None = None) -> None:
        """Start an episode; `seed` (the env's reset seed) seeds `rng`, the expert's own draws for the episode,
        kept apart from the env's stream so that they never echo the scene's."""
        self.rng = np.random.default_rng([EXPERT_STREAM, 0 if seed is None else seed])
        self.sequencer.reset()
        self.grasp_attempts = 0
        self.failure: str | None = None
        self.on_reset()

    def act(self, obs=None) -> np.ndarray:
        """The next step's joint targets, led by `lead` times the plan's joint velocity, and its gripper command."""
        previous = self.sequencer.last
        step = self.sequencer.next_step()
        q = step.q
        if previous is not None and self.lead > 0:
            q = q + self.lead * (step.q - previous.q) / self.dt
        return np.append(q, step.gripper).astype(np.float32)

    @property
    def phase(self) -> str | None:
        return self.sequencer.phase

    @property
    def tcp_target(self) -> np.ndarray | None:
        return None if self.sequencer.last is None else self.sequencer.last.tcp

    # -- state ----------------------------------------------------------------------------------------------------
    def _object_pose(self) -> np.ndarray:
        return pose_matrix(self.target_actor().pose)

    def _holding(self) -> bool:
        return bool(self.env.robot.is_grasping(self.target_actor()))

    def _tcp(self) -> np.ndarray:
        return pose_matrix(self.env.robot.tcp_pose())

    def _last(self) -> Step:
        """Where the next phase starts: the last commanded step (the measured joints before the first action)."""
        if self.sequencer.last is None:
            q = self.env.robot.arm_qpos().astype(np.float64)
            return Step(self.ik.fk(q), q, OPEN, "start")
        return self.sequencer.last

    # -- planning helpers -----------------------------------------------------------------------------------------
    def _timed(
        self, pose_at: Callable[[float], np.ndarray], start: Step, min_steps: int = 1, speed: float = 1.0
    ) -> TimedPath:
        """`pose_at` solved from `start` and timed at `speed` times the planner's joint limits."""
        return self.ik.plan(
            pose_at, start.q, speed * self.max_velocity, speed * self.max_acceleration, self.dt, min_steps=min_steps
        )

    def _fail(self, reason: str) -> list[Step]:
        """Give up: keep still (the episode runs out). The first reason given sticks."""
        self.failure = self.failure or reason
        return hold(self._last(), 1, phase="failed")


__all__ = ["PhasePlanner"]


def _same_kind(current: Any, value: Any) -> bool:
    """Whether `value` may replace a config field whose default is `current` (an int reads as a float; None
    fields take a number or None)."""
    if isinstance(current, bool) or isinstance(value, bool):
        return isinstance(current, bool) and isinstance(value, bool)
    if current is None or value is None:
        return value is None or isinstance(value, int | float)
    if isinstance(current, float):
        return isinstance(value, int | float)
    return type(value) is type(current)


def _kind_name(current: Any) -> str:
    if current is None:
        return "a number or null"
    return {bool: "true or false", int: "an integer", float: "a number"}.get(type(current), type(current).__name__)
