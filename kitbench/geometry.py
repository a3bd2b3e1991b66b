"""Rotation and pose maths on plain numpy (quaternions are w, x, y, z as in SAPIEN).

transforms3d (a SAPIEN dependency) is broken under numpy 2, so the few conversions kitbench needs live here.
"""

from __future__ import annotations

import math

import numpy as np


def quat_to_matrix(q) -> np.ndarray:
    w, x, y, z = (float(v) for v in q)
    n = w * w + x * x + y * y + z * z
    s = 2.0 / n if n > 0 else 0.0
    return np.array(
        [
            [1 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w)],
            [s * (x * y + z * w), 1 - s * (x * x + z * z), s * (y * z - x * w)],
            [s * (x * z - y * w), s * (y * z + x * w), 1 - s * (x * x + y * y)],
        ]
    )


def matrix_to_quat(m) -> np.ndarray:
    """Rotation matrix to a unit quaternion with w >= 0 (Shepperd's method, stable near 180 degrees)."""
    m = np.asarray(m, dtype=np.float64)
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif m[1, 1] > m[2, 2]:
        s = math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    quat = np.asarray(q, dtype=np.float64)
    quat /= np.linalg.norm(quat)
    return -quat if quat[0] < 0 else quat


def axis_angle_to_matrix(rotvec) -> np.ndarray:
    """Rodrigues' formula for a rotation vector (axis times angle)."""
    v = np.asarray(rotvec, dtype=np.float64)
    theta = float(np.linalg.norm(v))
    if theta < 1e-12:
        return np.eye(3)
    k = v / theta
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(theta) * kx + (1 - math.cos(theta)) * (kx @ kx)


def matrix_to_axis_angle(m) -> np.ndarray:
    q = matrix_to_quat(m)
    w = min(1.0, max(-1.0, q[0]))
    angle = 2 * math.acos(w)
    s = math.sqrt(max(0.0, 1 - w * w))
    if s < 1e-12:
        return np.zeros(3)
    return q[1:] / s * angle


def yaw_quat(yaw: float) -> np.ndarray:
    return np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])


def axis_quat(axis, angle: float) -> np.ndarray:
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    return np.concatenate([[math.cos(angle / 2)], math.sin(angle / 2) * a])


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> tuple[np.ndarray, np.ndarray]:
    """Camera pose (position, quaternion) in SAPIEN's camera convention: x forward, y left, z up."""
    eye = np.asarray(eye, dtype=np.float64)
    forward = np.asarray(target, dtype=np.float64) - eye
    forward /= np.linalg.norm(forward)
    left = np.cross(np.asarray(up, dtype=np.float64), forward)
    if np.linalg.norm(left) < 1e-9:  # looking straight up or down
        left = np.cross([0.0, 1.0, 0.0] if abs(forward[1]) < 0.9 else [1.0, 0.0, 0.0], forward)
    left /= np.linalg.norm(left)
    up_v = np.cross(forward, left)
    return eye, matrix_to_quat(np.stack([forward, left, up_v], axis=1))


def pose_to_matrix(p, q) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = quat_to_matrix(q)
    t[:3, 3] = p
    return t


def tilt_from_vertical(axis) -> float:
    """Angle between a direction and the vertical line, in [0, pi/2]: either end up counts as upright."""
    a = np.asarray(axis, dtype=np.float64)
    c = abs(a[2]) / max(float(np.linalg.norm(a)), 1e-12)
    return math.acos(min(1.0, c))


def planar_yaw(rotation) -> float:
    """Yaw of a body from its x axis projected on the table: robust where Euler angles are not."""
    r = np.asarray(rotation)
    x = r[:, 0]
    if math.hypot(x[0], x[1]) < 1e-6:  # x axis vertical: fall back on the y axis
        y = r[:, 1]
        return math.atan2(y[1], y[0]) - math.pi / 2
    return math.atan2(x[1], x[0])


def wrap_angle(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi
