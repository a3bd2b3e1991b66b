"""The control modes. Each maps an action (last entry: gripper, -1 closed .. 1 open) to arm joint targets.

End-effector modes solve IK with mink on the MuJoCo twin of the simulated Panda. Poses are in the robot's
base frame (x forward, z up, origin at the base).

An action is expressed as ManiSkill 3.0.1 expresses it (`action_space`, `decode`, `encode`): the delta modes
normalised to [-1, 1] (1 is 0.1 rad or 0.1 m), rotations as XYZ Euler triples (ManiSkill's `euler_angles_to_matrix`
order; a delta rotation clipped to norm 1 and scaled by its `rot_lower`, -0.1, so +1 turns the other way round).
Inside, each controller works in physical units (`physical_space`: radians, metres, axis-angle vectors):

| mode                      | arm action: from the measured state / the previous target | action: 1 is      |
|---------------------------|------------------------------------------------------------|-------------------|
| pd_joint_delta_pos        | joint position deltas from the measured joints             | 0.1 rad           |
| pd_joint_target_delta_pos | joint position deltas from the previous joint target       | 0.1 rad           |
| pd_joint_pos              | absolute joint targets (joint limits)                      | 1 rad             |
| pd_ee_delta_pos           | TCP translation from the measured TCP                      | 0.1 m             |
| pd_ee_target_delta_pos    | TCP translation from the previous TCP target               | 0.1 m             |
| pd_ee_delta_pose          | TCP translation, rotation from the measured TCP            | 0.1 m, -0.1 rad   |
| pd_ee_target_delta_pose   | TCP translation, rotation from the previous TCP target     | 0.1 m, -0.1 rad   |
| pd_ee_pose                | absolute TCP position (+-2 m), XYZ Euler rotation (+-2 pi) | 1 m, 1 rad        |

The names and semantics are ManiSkill's (docs/fidelity.md lists what still differs). A delta mode applies the
action to the measured state, which the observation holds, so the same observation and action always mean the
same target: a policy can learn it. A `*_target_delta_*` mode accumulates on the previous target, as a real arm's
impedance controller integrates commands (ten 1 cm steps move the TCP 10 cm once the arm settles, however the PD
drives lag); the target is state the observation does not show. So that a blocked arm does not wind up (a
difference from ManiSkill, which bounds nothing), an accumulated target never leads the measured state by more
than `MAX_JOINT_LEAD` / `MAX_POS_LEAD` / `MAX_ROT_LEAD`. Rotation deltas turn the TCP about axes parallel to the
base frame's, centred at the TCP. `pd_ee_delta_pos` keeps the orientation last
commanded: its action has no rotation, and a target built on the measured orientation would keep whatever a
contact or the drives' tracking error did to it instead of restoring it.

Each controller class describes its mode once, in `Controller`'s class attributes (frame, delta or target, action
names, units, noise units); the env's action names and units, action noise, the teleop mappings and the
joint-target expression read them (`controller_class`), so a new mode is one new class.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import numpy as np
from gymnasium import spaces
from scipy.spatial.transform import Rotation  # type: ignore[import-untyped]

from kitbench.control.noise_units import JOINT_UNIT, POSITION_UNIT, ROTATION_UNIT
from kitbench.errors import KitbenchError
from kitbench.geometry import axis_angle_to_matrix, matrix_to_axis_angle

if TYPE_CHECKING:  # importing it loads mink and MuJoCo, which joint modes never need
    from kitbench.control.kinematics import ArmKinematics

JOINTS = "joints"  # a mode's arm part is one entry per arm joint
BASE = "base"  # a mode's arm part is the TCP's, in the robot's base frame
# twice the lag of ManiSkill's gains at 2 rad/s (0.2 rad): at 0.2 the LiftPegUpright expert lost all 40 swings in
# pd_joint_target_delta_pos
MAX_JOINT_LEAD = 0.4  # rad
MAX_POS_LEAD = 0.1  # m
MAX_ROT_LEAD = 0.4  # rad
DELTA_BOUND = 0.1  # rad or m: what a delta action of 1 commands (ManiSkill's Panda and Fetch)
ROT_SCALE = -DELTA_BOUND  # ManiSkill scales a delta rotation by its `rot_lower`, -0.1: +1 turns the other way round


def euler_to_axis_angle(euler) -> np.ndarray:
    """An XYZ Euler triple as ManiSkill reads one (R = Rx @ Ry @ Rz) to an axis-angle vector."""
    return Rotation.from_euler("XYZ", np.asarray(euler, dtype=np.float64)).as_rotvec()


def axis_angle_to_euler(rotvec) -> np.ndarray:
    """`euler_to_axis_angle`'s inverse (angles in [-pi, pi], the middle one in [-pi/2, pi/2])."""
    return Rotation.from_rotvec(np.asarray(rotvec, dtype=np.float64)).as_euler("XYZ")


def _box(low, high) -> spaces.Box:
    low = np.append(np.asarray(low, dtype=np.float32), -1.0).astype(np.float32)
    high = np.append(np.asarray(high, dtype=np.float32), 1.0).astype(np.float32)
    return spaces.Box(low, high, dtype=np.float32)


def _limit_rotation_lead(target: np.ndarray, measured: np.ndarray) -> np.ndarray:
    rotvec = matrix_to_axis_angle(target @ measured.T)
    angle = float(np.linalg.norm(rotvec))
    if angle <= MAX_ROT_LEAD:
        return target
    return axis_angle_to_matrix(rotvec * (MAX_ROT_LEAD / angle)) @ measured


class Controller:
    """Keeps the arm's joint target (and, for end-effector modes, the TCP target) between steps.

    `action_space` is the action's box as ManiSkill has it; `physical_space` the same action in radians, metres
    and axis-angle vectors, which `arm_targets` takes; `decode` and `encode` turn the arm part of one into the other
    (the gripper's command is the same in both). The class attributes describe the mode; a JOINTS mode gives one
    unit and one noise unit for every joint, whatever their number."""

    mode: str  # ManiSkill's name for it
    frame: str  # JOINTS or BASE
    delta: bool  # the arm part moves the target by its amount (else it is the target)
    target_delta: bool = False  # a delta from the previous target (else from the measured state)
    turns: bool = False  # the arm part rotates the TCP (its last three entries)
    tcp_names: tuple[str, ...] = ()  # a BASE mode's arm entries
    units: tuple[str, ...]  # each arm entry's physical unit
    noise_units: tuple[float, ...]  # each arm entry's noise unit, in `units` (`kitbench.control.noise_units`)
    physical_space: spaces.Box

    @classmethod
    def action_names(cls, joint_names: Sequence[str]) -> list[str]:
        """The arm part's names, given the names of the robot's arm joints (a joint delta: `delta_<joint>`)."""
        if cls.frame == BASE:
            return list(cls.tcp_names)
        return [f"delta_{j}" if cls.delta else j for j in joint_names]

    @property
    def action_space(self) -> spaces.Box:
        return self.physical_space

    def decode(self, arm_action: np.ndarray) -> np.ndarray:
        """The arm part of an action, as ManiSkill expresses it, in physical units."""
        return np.asarray(arm_action, dtype=np.float64)

    def encode(self, arm: np.ndarray) -> np.ndarray:
        """`decode`'s inverse (unclipped: it can say how far outside the box a command lies)."""
        return np.asarray(arm, dtype=np.float64)

    def scale(self) -> np.ndarray:
        """Action units per physical unit of each arm entry, near zero (noise sizes)."""
        return np.ones(self.physical_space.shape[0] - 1)

    def __init__(self, arm_limits: np.ndarray, kinematics_factory: Callable[[], ArmKinematics]) -> None:
        self.arm_limits = arm_limits
        self._kinematics_factory = kinematics_factory
        self._kinematics: ArmKinematics | None = None
        self._body: np.ndarray | None = None  # where the joints outside the arm stand (set_body)
        self._joint_target: np.ndarray | None = None  # (7,) last arm joint target, set by reset()
        self.tcp_target: np.ndarray | None = None  # 4x4 base-frame TCP target of end-effector modes

    @property
    def kinematics(self) -> ArmKinematics:
        if self._kinematics is None:  # built on first use: joint modes never pay for MuJoCo
            self._kinematics = self._kinematics_factory()
            if self._body is not None:
                self._kinematics.set_body(self._body)
        return self._kinematics

    def set_body(self, body_qpos: np.ndarray) -> None:
        """The measured positions of the robot's body joints (a torso), which the arm's kinematics stand on."""
        self._body = np.asarray(body_qpos, dtype=np.float64)
        if self._kinematics is not None:
            self._kinematics.set_body(self._body)

    @property
    def joint_target(self) -> np.ndarray:
        """The (7,) last arm joint target."""
        if self._joint_target is None:
            raise RuntimeError("the controller has no joint target before reset()")
        return self._joint_target

    @joint_target.setter
    def joint_target(self, value: np.ndarray) -> None:
        self._joint_target = value

    def reset(self, arm_qpos: np.ndarray) -> None:
        self.joint_target = np.array(arm_qpos, dtype=np.float64)
        self.tcp_target = None

    def arm_targets(self, arm_action: np.ndarray, arm_qpos: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def preview(self, arm_action: np.ndarray, arm_qpos: np.ndarray) -> np.ndarray:
        """The (7,) joint targets `arm_action` would set from `arm_qpos`, leaving the controller as it was: to
        compare two actions (a policy's and a label) where they lead, whatever the mode."""
        saved = self._joint_target, self.tcp_target
        try:
            return self.arm_targets(np.asarray(arm_action, dtype=np.float64), arm_qpos).copy()
        finally:
            self._joint_target, self.tcp_target = saved

    def joint_action(self, arm_target: np.ndarray, arm_qpos: np.ndarray) -> np.ndarray:
        """The arm part (physical units) that drives the arm to the joint positions `arm_target` from `arm_qpos`: a
        delta is taken from what the mode applies it to, so the action reproduces the target where it fits the box."""
        if self.frame == BASE:
            return self.tcp_action(self.kinematics.tcp_pose(arm_target), arm_qpos)
        if not self.delta:
            return arm_target
        return arm_target - (self.joint_target if self.target_delta else arm_qpos)

    def tcp_action(self, target: np.ndarray, arm_qpos: np.ndarray) -> np.ndarray:
        """The arm part (physical units) of a BASE mode that drives the TCP to `target` (4x4) from `arm_qpos`."""
        if self.frame != BASE:
            raise ValueError(f"{self.mode} commands the arm's joints, not its TCP")
        if not self.delta:
            return pose_to_ee_action(target)
        previous = self.tcp_target if self.target_delta else None
        if previous is None:
            previous = self.kinematics.tcp_pose(arm_qpos)
        arm = target[:3, 3] - previous[:3, 3]
        if self.turns:
            arm = np.concatenate([arm, matrix_to_axis_angle(target[:3, :3] @ previous[:3, :3].T)])
        return arm

    def _clip_to_limits(self, q: np.ndarray) -> np.ndarray:
        return np.clip(q, self.arm_limits[:, 0], self.arm_limits[:, 1])

    def _solve(self, target: np.ndarray) -> np.ndarray:
        self.tcp_target = target
        q, _ = self.kinematics.solve(target, self.joint_target)
        self.joint_target = self._clip_to_limits(q)
        return self.joint_target


class _Normalised(Controller):
    """A delta mode: ManiSkill's action in [-1, 1], `DELTA_BOUND` a unit."""

    delta = True

    @functools.cached_property
    def action_space(self) -> spaces.Box:  # built once: the env reads it every step
        n = self.physical_space.shape[0]
        return spaces.Box(-np.ones(n, dtype=np.float32), np.ones(n, dtype=np.float32), dtype=np.float32)

    def decode(self, arm_action):
        return np.clip(np.asarray(arm_action, dtype=np.float64), -1.0, 1.0) * DELTA_BOUND

    def encode(self, arm):
        return np.asarray(arm, dtype=np.float64) / DELTA_BOUND

    def scale(self):
        return np.full(self.physical_space.shape[0] - 1, 1.0 / DELTA_BOUND)


class JointDeltaPos(_Normalised):
    """Joint deltas from the measured joint positions."""

    mode = "pd_joint_delta_pos"
    frame = JOINTS
    units = ("rad",)
    noise_units = (JOINT_UNIT,)

    def __init__(self, arm_limits, kinematics_factory):
        super().__init__(arm_limits, kinematics_factory)
        n = len(arm_limits)
        self.physical_space = _box(np.full(n, -0.1), np.full(n, 0.1))

    def arm_targets(self, arm_action, arm_qpos):
        self.joint_target = self._clip_to_limits(arm_qpos + arm_action)
        return self.joint_target


class JointTargetDeltaPos(JointDeltaPos):
    """Joint deltas accumulated on the previous joint target (at most `MAX_JOINT_LEAD` ahead of the joints)."""

    mode = "pd_joint_target_delta_pos"
    target_delta = True

    def arm_targets(self, arm_action, arm_qpos):
        target = np.clip(self.joint_target + arm_action, arm_qpos - MAX_JOINT_LEAD, arm_qpos + MAX_JOINT_LEAD)
        self.joint_target = self._clip_to_limits(target)
        return self.joint_target


class JointPos(Controller):
    mode = "pd_joint_pos"
    frame = JOINTS
    delta = False
    units = ("rad",)
    noise_units = (JOINT_UNIT,)

    def __init__(self, arm_limits, kinematics_factory):
        super().__init__(arm_limits, kinematics_factory)
        self.physical_space = _box(arm_limits[:, 0], arm_limits[:, 1])

    def arm_targets(self, arm_action, arm_qpos):
        self.joint_target = self._clip_to_limits(arm_action.astype(np.float64))
        return self.joint_target


class _EEDelta(_Normalised):
    """Shared by the delta end-effector modes: the delta applies to the measured TCP pose, or (`target_delta`) to
    the previous TCP target with a bounded lead over the measured TCP."""

    frame = BASE

    def _delta_target(self, translation, rotation, arm_qpos) -> np.ndarray:
        measured = self.kinematics.tcp_pose(arm_qpos)
        previous = self.tcp_target
        target = (previous if self.target_delta and previous is not None else measured).copy()
        target[:3, 3] = np.clip(
            target[:3, 3] + translation, measured[:3, 3] - MAX_POS_LEAD, measured[:3, 3] + MAX_POS_LEAD
        )
        if rotation is not None:
            target[:3, :3] = _limit_rotation_lead(axis_angle_to_matrix(rotation) @ target[:3, :3], measured[:3, :3])
        elif previous is not None:  # translation only: the orientation last commanded (module docstring)
            target[:3, :3] = previous[:3, :3]
        return self._solve(target)


class EEDeltaPos(_EEDelta):
    mode = "pd_ee_delta_pos"
    tcp_names = ("dx", "dy", "dz")
    units = ("m",) * 3
    noise_units = (POSITION_UNIT,) * 3

    def __init__(self, arm_limits, kinematics_factory):
        super().__init__(arm_limits, kinematics_factory)
        self.physical_space = _box(np.full(3, -0.1), np.full(3, 0.1))

    def arm_targets(self, arm_action, arm_qpos):
        return self._delta_target(arm_action[:3], None, arm_qpos)


class EETargetDeltaPos(EEDeltaPos):
    mode = "pd_ee_target_delta_pos"
    target_delta = True


class EEDeltaPose(_EEDelta):
    mode = "pd_ee_delta_pose"
    turns = True
    tcp_names = ("dx", "dy", "dz", "drx", "dry", "drz")
    units = ("m",) * 3 + ("rad",) * 3
    noise_units = (POSITION_UNIT,) * 3 + (ROTATION_UNIT,) * 3

    def __init__(self, arm_limits, kinematics_factory):
        super().__init__(arm_limits, kinematics_factory)
        self.physical_space = _box(np.full(6, -0.1), np.full(6, 0.1))

    def arm_targets(self, arm_action, arm_qpos):
        return self._delta_target(arm_action[:3], arm_action[3:6], arm_qpos)

    def decode(self, arm_action):
        """Translation as every delta mode; the rotation an XYZ Euler triple, clipped to norm 1 (ManiSkill clips
        it by norm, not by entry) and scaled by `ROT_SCALE`."""
        a = np.asarray(arm_action, dtype=np.float64)
        rotation = a[3:6] / max(1.0, float(np.linalg.norm(a[3:6])))
        return np.concatenate([super().decode(a[:3]), euler_to_axis_angle(rotation * ROT_SCALE)])

    def encode(self, arm):
        p = np.asarray(arm, dtype=np.float64)
        return np.concatenate([super().encode(p[:3]), axis_angle_to_euler(p[3:6]) / ROT_SCALE])


class EETargetDeltaPose(EEDeltaPose):
    mode = "pd_ee_target_delta_pose"
    target_delta = True


class EEPose(Controller):
    mode = "pd_ee_pose"
    frame = BASE
    delta = False
    turns = True
    tcp_names = ("x", "y", "z", "rx", "ry", "rz")
    units = ("m",) * 3 + ("rad",) * 3
    noise_units = (POSITION_UNIT,) * 3 + (ROTATION_UNIT,) * 3

    def __init__(self, arm_limits, kinematics_factory, position_bound: float = 2.0):
        """`position_bound`: the position box (m) around the base frame's origin (ManiSkill's Panda: 2 m)."""
        super().__init__(arm_limits, kinematics_factory)
        b, r = position_bound, 2 * np.pi  # ManiSkill's rotation bounds for an absolute pose
        self.physical_space = _box([-b, -b, -b, -np.pi, -np.pi, -np.pi], [b, b, b, np.pi, np.pi, np.pi])
        self._action_space = _box([-b, -b, -b, -r, -r, -r], [b, b, b, r, r, r])

    @property
    def action_space(self) -> spaces.Box:
        return self._action_space

    def decode(self, arm_action):
        a = np.asarray(arm_action, dtype=np.float64)
        return np.concatenate([a[:3], euler_to_axis_angle(a[3:6])])

    def encode(self, arm):
        p = np.asarray(arm, dtype=np.float64)
        return np.concatenate([p[:3], axis_angle_to_euler(p[3:6])])

    def arm_targets(self, arm_action, arm_qpos):
        target = np.eye(4)
        target[:3, :3] = axis_angle_to_matrix(arm_action[3:6])
        target[:3, 3] = arm_action[:3]
        return self._solve(target)


def pose_to_ee_action(tcp_pose: np.ndarray) -> np.ndarray:
    """The `pd_ee_pose` arm action that commands a 4x4 base-frame TCP pose."""
    return np.concatenate([tcp_pose[:3, 3], matrix_to_axis_angle(tcp_pose[:3, :3])])


_CONTROLLERS = {
    c.mode: c
    for c in (
        JointDeltaPos,
        JointTargetDeltaPos,
        JointPos,
        EEDeltaPos,
        EETargetDeltaPos,
        EEDeltaPose,
        EETargetDeltaPose,
        EEPose,
    )
}
CONTROL_MODES = tuple(_CONTROLLERS)


def controller_class(mode: str) -> type[Controller]:
    """The class that controls and describes `mode`."""
    if mode not in _CONTROLLERS:
        raise KitbenchError(f"unknown control_mode {mode!r}; valid choices: {', '.join(CONTROL_MODES)}")
    return _CONTROLLERS[mode]


def modes_where(test: Callable[[type[Controller]], bool]) -> tuple[str, ...]:
    """The control modes, in `CONTROL_MODES`' order, whose controller class passes `test`."""
    return tuple(mode for mode, cls in _CONTROLLERS.items() if test(cls))


def make_controller(
    mode: str,
    arm_limits: np.ndarray,
    kinematics_factory: Callable[[], ArmKinematics],
    position_bound: float = 2.0,
) -> Controller:
    cls = controller_class(mode)
    if cls is EEPose:
        return EEPose(arm_limits, kinematics_factory, position_bound)
    return cls(arm_limits, kinematics_factory)
