"""Time parametrisation: how fast a scripted expert moves along a joint path.

Every path is timed rest to rest, as fast as the robot's joint velocity and acceleration limits allow
(`time_parametrize`; `RobotSpec.arm_velocity_limits` / `arm_acceleration_limits`), so an expert's speed comes
from the robot's limits rather than hand-tuned step counts, and its demonstrations stay within what the real arm
can do.
"""

from __future__ import annotations

import math

import numpy as np


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


def _max_speed_squared(
    dq: np.ndarray, d2q: np.ndarray, max_velocity: np.ndarray, max_acceleration: np.ndarray
) -> float:
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


def time_parametrize(
    q: np.ndarray, max_velocity: np.ndarray, max_acceleration: np.ndarray, dt: float, min_steps: int = 1
) -> np.ndarray:
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


__all__ = ["time_parametrize"]
