"""Shared machinery for scripted experts: TCP pose paths, their timing, IK through `PandaKinematics` and phases.

Experts command `pd_joint_pos`: every control step they send the joint targets that reach one TCP pose of a
planned path. Planning in joint space keeps the expert independent of the end-effector controllers' lead limits,
and solving each waypoint from the previous solution keeps the arm on one IK branch (differential IK is local).

A path is a function s -> TCP pose, s in [0, 1]. `ArmIK.plan` solves it densely and times it, rest to rest, as
fast as the Panda's joint velocity and acceleration limits allow (`time_parametrize`), so an expert's speed comes
from the robot's limits rather than hand-tuned step counts, and its demonstrations stay within what the real
arm can do. `PhaseSequencer` plays the resulting steps phase by phase, planning each phase when it starts.

Poses are 4x4 matrices in the world frame; `ArmIK` converts to the robot base frame `PandaKinematics` uses.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

from kitbench.control.kinematics import ARM_VELOCITY_LIMITS, PandaKinematics
from kitbench.geometry import axis_angle_to_matrix, matrix_to_axis_angle, pose_to_matrix

ARM_MAX_VELOCITY = np.array(list(ARM_VELOCITY_LIMITS.values()))  # rad/s, the real Panda's joint limits
ARM_MAX_ACCELERATION = np.array([15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0])  # rad/s^2, Franka's datasheet


# -- poses --------------------------------------------------------------------------------------------------------


def pose_matrix(pose) -> np.ndarray:
    """A SAPIEN pose as a 4x4 matrix."""
    return pose_to_matrix(pose.p, pose.q)


def make_pose(rotation: np.ndarray, position) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = rotation
    t[:3, 3] = position
    return t


def rot_y(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rotation_angle(a: np.ndarray, b: np.ndarray) -> float:
    """Angle (rad) of the rotation between two rotation matrices."""
    return float(np.linalg.norm(matrix_to_axis_angle(a.T @ b)))


def interpolate_pose(a: np.ndarray, b: np.ndarray, s: float) -> np.ndarray:
    """Pose a fraction `s` of the way from `a` to `b`: straight-line position, shortest-arc rotation."""
    rotvec = matrix_to_axis_angle(a[:3, :3].T @ b[:3, :3])
    return make_pose(a[:3, :3] @ axis_angle_to_matrix(s * rotvec), (1 - s) * a[:3, 3] + s * b[:3, 3])


def smoothstep(s: float) -> float:
    """Cubic ease-in/out on [0, 1] (zero slope at both ends): schedules one part of a path inside another."""
    s = min(1.0, max(0.0, s))
    return s * s * (3.0 - 2.0 * s)


def cubic_bezier(p0, p1, p2, p3, s: float) -> np.ndarray:
    """A smooth curve from p0 to p3 leaving along p1 - p0 and arriving along p3 - p2."""
    u = 1.0 - s
    return u**3 * p0 + 3 * u * u * s * p1 + 3 * u * s * s * p2 + s**3 * p3


# -- inverse kinematics -------------------------------------------------------------------------------------------


@dataclass
class IKResult:
    qs: list[np.ndarray]
    position_error: float  # worst over the path, m
    rotation_error: float  # worst over the path, rad
    min_limit_margin: float  # smallest distance of any joint to its limit over the path, rad

    def ok(self, position_tol: float = 2e-3, rotation_tol: float = 2e-2) -> bool:
        return self.position_error <= position_tol and self.rotation_error <= rotation_tol


class ArmIK:
    """World-frame TCP poses to Panda arm joint targets, each waypoint solved from the previous solution.

    A pose the arm cannot reach shows up as a residual error (mink stalls against a joint limit or the
    velocity limit per iteration), so callers check `IKResult.ok` rather than trusting a converged flag: a
    waypoint a few millimetres off is still a usable target for the PD drives.
    """

    def __init__(self, base_pose: np.ndarray, kinematics: PandaKinematics | None = None):
        self.base = base_pose
        self.base_inv = np.linalg.inv(base_pose)
        self.kin = kinematics or PandaKinematics()
        self.limits = self.kin.model.jnt_range[:7].copy()

    def to_base(self, world_pose: np.ndarray) -> np.ndarray:
        return self.base_inv @ world_pose

    def fk(self, q: np.ndarray) -> np.ndarray:
        """World TCP pose of arm joint positions `q`."""
        return self.base @ self.kin.tcp_pose(q)

    def solve_path(self, poses: Iterable[np.ndarray], q_init: np.ndarray) -> IKResult:
        q = np.asarray(q_init, dtype=np.float64)
        qs, pos_err, rot_err, margin = [], 0.0, 0.0, np.inf
        for pose in poses:
            target = self.to_base(pose)
            q, _ = self.kin.solve(target, q)
            q = np.clip(q, self.limits[:, 0], self.limits[:, 1])
            reached = self.kin.tcp_pose(q)
            pos_err = max(pos_err, float(np.linalg.norm(reached[:3, 3] - target[:3, 3])))
            rot_err = max(rot_err, rotation_angle(reached[:3, :3], target[:3, :3]))
            margin = min(margin, float(np.min(np.minimum(q - self.limits[:, 0], self.limits[:, 1] - q))))
            qs.append(q.copy())
        return IKResult(qs, pos_err, rot_err, margin)

    def plan(self, pose_at: Callable[[float], np.ndarray], q_init: np.ndarray, max_velocity: np.ndarray,
             max_acceleration: np.ndarray, dt: float, resolution: tuple[float, float] = (0.005, 0.025),
             min_steps: int = 1) -> TimedPath:
        """Solve a parametric TCP path `pose_at(s)`, s in [0, 1], and time it as fast as the joint limits allow.

        The path is solved at samples `resolution` (m, rad) apart, each from the previous solution, then timed
        from rest to rest (`time_parametrize`); the joint targets of each control step interpolate the samples.
        """
        samples = path_samples(pose_at, *resolution)
        result = self.solve_path([pose_at(s) for s in samples], q_init)
        q = np.vstack([q_init, *result.qs])
        s_steps = time_parametrize(q, max_velocity, max_acceleration, dt, min_steps)
        grid = np.concatenate([[0.0], samples])
        q_steps = [np.array([np.interp(s, grid, q[:, j]) for j in range(q.shape[1])]) for s in s_steps]
        return TimedPath([pose_at(s) for s in s_steps], q_steps, result)


@dataclass
class TimedPath:
    poses: list[np.ndarray]  # TCP target of each control step (world)
    qs: list[np.ndarray]  # joint targets of each control step
    ik: IKResult  # of the dense samples the steps interpolate


def path_samples(pose_at: Callable[[float], np.ndarray], step: float, angle_step: float,
                 min_samples: int = 4, max_samples: int = 64) -> np.ndarray:
    """Path parameters (excluding 0) dense enough that consecutive poses are about `step` / `angle_step` apart."""
    probe = [pose_at(s) for s in np.linspace(0.0, 1.0, 11)]
    length = sum(float(np.linalg.norm(b[:3, 3] - a[:3, 3])) for a, b in zip(probe, probe[1:]))
    angle = sum(rotation_angle(a[:3, :3], b[:3, :3]) for a, b in zip(probe, probe[1:]))
    n = int(np.clip(math.ceil(max(length / step, angle / angle_step)), min_samples, max_samples))
    return np.linspace(0.0, 1.0, n + 1)[1:]


def _acceleration_intervals(dq: np.ndarray, d2q: np.ndarray, max_acceleration: np.ndarray):
    """Each moving joint's acceleration q' s_ddot + q'' s_dot^2 stays within its limit for s_ddot in
    [k v2 - w, k v2 + w], v2 = s_dot^2: returns (k, w) of the joints that move along the path here."""
    moving = np.abs(dq) > 1e-9
    return -d2q[moving] / dq[moving], max_acceleration[moving] / np.abs(dq[moving])


def _acceleration_bounds(dq: np.ndarray, d2q: np.ndarray, v2: float, max_acceleration: np.ndarray):
    """The range of s_ddot at path speed s_dot^2 = v2 that keeps every joint within its acceleration limit."""
    k, w = _acceleration_intervals(dq, d2q, max_acceleration)
    if len(k) == 0:
        return -np.inf, np.inf
    return float(np.max(k * v2 - w)), float(np.min(k * v2 + w))


def _max_speed_squared(dq: np.ndarray, d2q: np.ndarray, max_velocity: np.ndarray,
                       max_acceleration: np.ndarray) -> float:
    """The largest s_dot^2 under the velocity limits at which some s_ddot meets every acceleration limit.

    The intervals of two moving joints overlap while |k_i - k_j| v2 <= w_i + w_j. On top of that the curvature
    term alone is kept within each joint's limit, |q''| v2 <= A: conservative, but without it the passes race
    through points where a joint turns back (q' ~ 0, where only an extreme s_ddot keeps it within its limit),
    which the 20 Hz control steps then turn into acceleration spikes.
    """
    cap = float(np.min(max_velocity**2 / np.maximum(dq**2, 1e-18)))
    cap = min(cap, float(np.min(max_acceleration / np.maximum(np.abs(d2q), 1e-12))))
    k, w = _acceleration_intervals(dq, d2q, max_acceleration)
    spread = np.abs(k[:, None] - k[None, :])
    apart = spread > 1e-12
    if apart.any():
        cap = min(cap, float(np.min((w[:, None] + w[None, :])[apart] / spread[apart])))
    return cap


def time_parametrize(q: np.ndarray, max_velocity: np.ndarray, max_acceleration: np.ndarray, dt: float,
                     min_steps: int = 1) -> np.ndarray:
    """Path parameter at each control step for the joint path `q` (rows at uniform s in [0, 1], rest to rest).

    Time-optimal parametrisation by numerical integration: the speed limit curve (joint velocity limits, and
    the speed above which the path's bends need more than the acceleration limits), a forward pass at maximum
    acceleration and a backward pass at maximum deceleration, each joint's acceleration being
    q' s_ddot + q'' s_dot^2; the path acceleration is constant between samples. The duration is rounded up to
    whole control steps by slowing down uniformly, so the last step lands on s = 1.
    """
    n = len(q)
    s = np.linspace(0.0, 1.0, n)
    ds = s[1] - s[0]
    dq = np.gradient(q, s, axis=0)
    d2q = np.gradient(dq, s, axis=0)
    v2 = np.array([_max_speed_squared(dq[i], d2q[i], max_velocity, max_acceleration) for i in range(n)])
    v2[0] = v2[-1] = 0.0
    for i in range(1, n):
        upper = _acceleration_bounds(dq[i - 1], d2q[i - 1], v2[i - 1], max_acceleration)[1]
        v2[i] = min(v2[i], v2[i - 1] + 2.0 * max(upper, 0.0) * ds)
    for i in range(n - 2, -1, -1):
        lower = _acceleration_bounds(dq[i + 1], d2q[i + 1], v2[i + 1], max_acceleration)[0]
        v2[i] = min(v2[i], v2[i + 1] - 2.0 * min(lower, 0.0) * ds)
    v = np.sqrt(np.maximum(v2, 0.0))
    segment_time = 2.0 * ds / np.maximum(v[:-1] + v[1:], 1e-12)
    t = np.concatenate([[0.0], np.cumsum(segment_time)])
    steps = max(min_steps, math.ceil(t[-1] / dt - 1e-9))
    scale = t[-1] / (steps * dt)  # < 1: the uniform slow-down that fills whole steps
    times = np.arange(1, steps + 1) * dt * scale
    i = np.clip(np.searchsorted(t, times, side="right") - 1, 0, n - 2)
    tau = times - t[i]
    accel = (v[i + 1] ** 2 - v[i] ** 2) / (2.0 * ds)
    out = np.minimum(s[i] + v[i] * tau + 0.5 * accel * tau**2, 1.0)
    out[-1] = 1.0
    return out


# -- phases -------------------------------------------------------------------------------------------------------


@dataclass
class Step:
    """One control step of a plan: the TCP target (world, for logging), its joint targets, the gripper command
    and the name of the phase it belongs to."""

    tcp: np.ndarray
    q: np.ndarray
    gripper: float
    phase: str


def steps_from(path: TimedPath, gripper: float, phase: str) -> list[Step]:
    return [Step(p, q, float(gripper), phase) for p, q in zip(path.poses, path.qs, strict=True)]


def hold(step: Step, count: int, gripper: float | None = None, phase: str | None = None) -> list[Step]:
    """`count` copies of a step, optionally with another gripper command or phase name (waiting for drives)."""
    g = step.gripper if gripper is None else gripper
    return [Step(step.tcp, step.q, g, phase or step.phase) for _ in range(count)]


class PhaseSequencer:
    """Plays planned steps; when they run out it asks `plan_next(finished_phase)` for the next phase's steps.

    Each phase is planned when it starts, from the simulated state at that moment, so an expert closes the
    loop between phases (a grasp is checked before the lift is planned from where the object really is) while
    staying open loop, hence smooth and fast, within a phase. A plan may hold steps of several consecutive
    phases (one smooth motion through approach and descent); `phase` is the name of the step being played.
    """

    def __init__(self, plan_next: Callable[[str | None], list[Step]]):
        self._plan_next = plan_next
        self._steps: deque[Step] = deque()
        self.last: Step | None = None

    @property
    def phase(self) -> str | None:
        return None if self.last is None else self.last.phase

    def reset(self) -> None:
        self._steps, self.last = deque(), None

    def next_step(self, max_empty_plans: int = 8) -> Step:
        for _ in range(max_empty_plans):
            if self._steps:
                self.last = self._steps.popleft()
                return self.last
            self._steps = deque(self._plan_next(self.phase))
        raise RuntimeError(f"after phase {self.phase!r}: {max_empty_plans} plans in a row had no steps")
