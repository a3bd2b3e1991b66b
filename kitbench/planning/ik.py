"""Inverse kinematics for scripted experts: TCP pose paths to timed arm joint targets, through `ArmKinematics`.

Experts command `pd_joint_pos`: every control step they send the joint targets that reach one TCP pose of a
planned path. Planning in joint space keeps the expert independent of the end-effector controllers' lead limits,
and solving each waypoint from the previous solution keeps the arm on one IK branch (differential IK is local).

A path is a function s -> TCP pose, s in [0, 1]. `ArmIK.plan` solves it densely and times it with
`timing.time_parametrize`. Poses are 4x4 matrices in the world frame; `ArmIK` converts to the robot base frame
`ArmKinematics` uses.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from itertools import pairwise

import numpy as np

from kitbench.control.kinematics import ArmKinematics, arm_joint_limits
from kitbench.planning.poses import rotation_angle
from kitbench.planning.timing import time_parametrize


@dataclass
class IKResult:
    qs: list[np.ndarray]
    position_error: float  # worst over the path, m
    rotation_error: float  # worst over the path, rad
    min_limit_margin: float  # smallest distance of any joint to its limit over the path, rad

    def ok(self, position_tol: float = 2e-3, rotation_tol: float = 2e-2) -> bool:
        return self.position_error <= position_tol and self.rotation_error <= rotation_tol


@dataclass
class TimedPath:
    poses: list[np.ndarray]  # TCP target of each control step (world)
    qs: list[np.ndarray]  # joint targets of each control step
    ik: IKResult  # of the dense samples the steps interpolate


class ArmIK:
    """World-frame TCP poses to arm joint targets, each waypoint solved from the previous solution.

    A pose the arm cannot reach shows up as a residual error (mink stalls against a joint limit or the
    velocity limit per iteration), so callers check `IKResult.ok` rather than trusting a converged flag: a
    waypoint a few millimetres off is still a usable target for the PD drives.
    """

    def __init__(self, base_pose: np.ndarray, kinematics: ArmKinematics):
        self.base = base_pose
        self.base_inv = np.linalg.inv(base_pose)
        self.kin = kinematics
        self.limits = arm_joint_limits(kinematics.spec)

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

    def plan(
        self,
        pose_at: Callable[[float], np.ndarray],
        q_init: np.ndarray,
        max_velocity: np.ndarray,
        max_acceleration: np.ndarray,
        dt: float,
        resolution: tuple[float, float] = (0.005, 0.025),
        min_steps: int = 1,
    ) -> TimedPath:
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


def path_samples(
    pose_at: Callable[[float], np.ndarray], step: float, angle_step: float, min_samples: int = 4, max_samples: int = 64
) -> np.ndarray:
    """Path parameters (excluding 0) dense enough that consecutive poses are about `step` / `angle_step` apart."""
    probe = [pose_at(s) for s in np.linspace(0.0, 1.0, 11)]
    length = sum(float(np.linalg.norm(b[:3, 3] - a[:3, 3])) for a, b in pairwise(probe))
    angle = sum(rotation_angle(a[:3, :3], b[:3, :3]) for a, b in pairwise(probe))
    n = int(np.clip(math.ceil(max(length / step, angle / angle_step)), min_samples, max_samples))
    return np.linspace(0.0, 1.0, n + 1)[1:]


__all__ = ["ArmIK", "IKResult", "TimedPath", "path_samples"]
