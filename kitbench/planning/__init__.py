"""Scripted experts: the machinery they share, one concept a module, and one planner module per task.

- `poses`: 4x4 pose maths and path shapes (interpolation, ease-in/out, Bezier curves), `HAND_DOWN`, and
  `upright_correction` (the hand motion that stands a held object upright).
- `timing`: time-optimal parametrisation of a joint path within the Panda's velocity and acceleration limits.
- `ik`: `ArmIK`, TCP pose paths to timed joint targets.
- `phases`: `Step`, `PhaseSequencer` and the gripper commands `OPEN` / `CLOSED`.
- `planner`: `PhasePlanner`, the base class of every task's expert.

The experts themselves live in `kitbench.planning.<task module>` (e.g. `kitbench.planning.lift_peg_upright`);
this package names no task, so importing it pulls in no task code.
"""

from kitbench.planning.ik import ArmIK, IKResult, TimedPath, path_samples
from kitbench.planning.phases import (
    CLOSED,
    OPEN,
    PhaseSequencer,
    Step,
    hold,
    steps_from,
)
from kitbench.planning.planner import PhasePlanner
from kitbench.planning.poses import (
    HAND_DOWN,
    cubic_bezier,
    interpolate_pose,
    make_pose,
    pose_matrix,
    rot_y,
    rot_z,
    rotation_angle,
    smoothstep,
)
from kitbench.planning.timing import time_parametrize

__all__ = [
    "CLOSED",
    "HAND_DOWN",
    "OPEN",
    "ArmIK",
    "IKResult",
    "PhasePlanner",
    "PhaseSequencer",
    "Step",
    "TimedPath",
    "cubic_bezier",
    "hold",
    "interpolate_pose",
    "make_pose",
    "path_samples",
    "pose_matrix",
    "rot_y",
    "rot_z",
    "rotation_angle",
    "smoothstep",
    "steps_from",
    "time_parametrize",
]
