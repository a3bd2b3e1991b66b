"""A person's joint targets held to the real arm's joint speeds (`JointRateLimiter`), as its servos would follow
them: each control step the commanded target moves from the last commanded one toward the requested one by at most
`max_speed * dt` per joint (rate-limited, never clipped in position: a leader moved fast is caught up over the steps
the servo needs). The speeds are the robot's `joint_speed_limits` (the SO-101's STS3215 4.7 rad/s, the Panda's
2.175/2.61 rad/s, the Fetch's URDF limits).

The jaw is not limited: the simulated jaw is the same drive for every source (the experts' grasps close it in two
control periods, docs/robots.md), so limiting a person's jaw alone would make human grasps differ from the expert's
on the same follower.
"""

from __future__ import annotations

import numpy as np

from kitbench.errors import KitbenchError
from kitbench.robots.spec import RobotSpec

# Below this (rad) a step is within the limit: float noise in a target converted from degrees is no limiting.
TOLERANCE = 1e-9


class JointRateLimiter:
    """Rate-limits joint targets (radians, one per joint) to `max_speed` (rad/s) at a control period `dt` (s);
    `limited_steps` counts the steps since `reset` where any joint was limited."""

    def __init__(self, max_speed: np.ndarray, dt: float):
        speed = np.asarray(max_speed, dtype=np.float64)
        if speed.ndim != 1 or not speed.size or not np.all(np.isfinite(speed)) or np.any(speed <= 0):
            raise KitbenchError(f"joint speed limits must be positive numbers, one per joint, got {max_speed!r}")
        if not dt > 0:
            raise KitbenchError(f"a control period must be positive, got {dt!r}")
        self.max_speed, self.dt = speed, float(dt)
        self.max_step = speed * self.dt
        self.previous: np.ndarray | None = None
        self.limited_steps = 0

    @classmethod
    def for_robot(cls, spec: RobotSpec, dt: float) -> JointRateLimiter:
        """The limiter of `spec`'s arm joints at its declared `joint_speed_limits`."""
        if len(spec.joint_speed_limits) != len(spec.arm_joints):
            raise KitbenchError(
                f"{spec.uid}: joint_speed_limits has {len(spec.joint_speed_limits)} entries for "
                f"{len(spec.arm_joints)} arm joints"
            )
        return cls(np.asarray(spec.joint_speed_limits), dt)

    def steps_to_reach(self, start: np.ndarray, target: np.ndarray) -> int:
        """The control steps the servos need to go from `start` to `target`."""
        distance = np.abs(np.asarray(target, dtype=np.float64) - np.asarray(start, dtype=np.float64))
        return int(np.max(np.ceil((distance - TOLERANCE) / self.max_step)).clip(min=0))

    def reset(self, q: np.ndarray) -> None:
        """A new episode: the last commanded target is `q` (where the arm stands), nothing limited yet."""
        q = np.asarray(q, dtype=np.float64)
        if q.shape != self.max_speed.shape:
            raise KitbenchError(f"a joint rate limiter of {self.max_speed.size} joints reset to {q.shape[0]} values")
        self.previous = q.copy()
        self.limited_steps = 0

    def __call__(self, target: np.ndarray) -> tuple[np.ndarray, bool]:
        """The target commanded this step (at most `max_step` from the last one, per joint) and whether any joint
        was limited."""
        if self.previous is None:
            raise RuntimeError("reset() the joint rate limiter before the first target")
        step = np.asarray(target, dtype=np.float64) - self.previous
        limited = bool(np.any(np.abs(step) > self.max_step + TOLERANCE))
        commanded = self.previous + np.clip(step, -self.max_step, self.max_step)
        self.previous = commanded
        self.limited_steps += limited
        return commanded.copy(), limited
