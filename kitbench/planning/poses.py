"""Pose maths for scripted experts: 4x4 poses, rotations about one axis, pose interpolation and path shapes.

Poses are 4x4 matrices in the world frame unless a name says otherwise (`ik.ArmIK` converts to the robot base
frame). A path is a function s -> TCP pose, s in [0, 1]; the helpers here build such functions, `ik.ArmIK.plan`
solves and times them.
"""

from __future__ import annotations

import math

import numpy as np

from kitbench.geometry import axis_angle_to_matrix, matrix_to_axis_angle, pose_to_matrix

HAND_DOWN = np.diag([1.0, -1.0, -1.0])  # TCP pointing down, hand x along the frame's x, fingers closing along its y


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


def upright_correction(pose: np.ndarray, goal_height: float, tilt: float | None = None) -> np.ndarray:
    """The world transform that stands a held object upright (its x axis vertical, turned about the horizontal
    axis of its tilt) with its centre at `goal_height`: applied to the hand holding it, it carries the object
    there as it is held now. `tilt`: the object's tilt as the caller measured it (else from its unit x axis)."""
    axis = pose[:3, 0] if pose[2, 0] >= 0 else -pose[:3, 0]
    if tilt is None:
        tilt = math.acos(min(1.0, abs(float(axis[2]))))
    rotvec = np.cross(axis, [0.0, 0.0, 1.0])
    rotvec *= tilt / max(float(np.linalg.norm(rotvec)), 1e-12)
    goal = make_pose(axis_angle_to_matrix(rotvec) @ pose[:3, :3], pose[:3, 3] + [0.0, 0.0, goal_height - pose[2, 3]])
    return goal @ np.linalg.inv(pose)


__all__ = [
    "HAND_DOWN",
    "cubic_bezier",
    "interpolate_pose",
    "make_pose",
    "pose_matrix",
    "rot_y",
    "rot_z",
    "rotation_angle",
    "smoothstep",
    "upright_correction",
]
