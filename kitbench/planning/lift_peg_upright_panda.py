"""The Panda's expert for LiftPegUpright-v1, the hooks of `lift_peg_upright.LiftPegUprightBase`: grasp the lying
peg from above and swing it upright, held, onto the table.

Why this motion. The peg lies along x, so the fingers close along y and the peg turns about y; the hand turns
with it by 90 degrees, so the grasp pitch decides the final one. The peg is grasped from straight above at its
centre (no gravity torque on the grasp) and its far end swings down: the hand ends horizontal, pointing back at
the robot, which the arm reaches with the TCP up to base-frame x ~0.45 only, so the peg is carried back while
it turns (the TCP ends at base-frame x = 0.4). The swing is planned around the peg's far end: it leaves the
table as the peg tilts, travels just above it and stops 2 mm above the table with the peg vertical, held at
the success height. Success ends an episode there; an episode that runs on (`kitbench record --settle-steps`)
sees the finish: the hand sets the peg down on the table and lets go, so the table fixes its height.

Every motion is timed as fast as the Panda's joint velocity and acceleration limits allow (`ik.ArmIK.plan`).
Measured alternatives (steps to success, 50 allowed; all variants solved every seed):
- as above (seeds 0-499): median 27, p90 28, max 29;
- grasping 3 or 6 cm from the centre towards the robot (less carrying, seeds 0-199): median 27 / 28, max 30 /
  32; the peg does not slip in this swing even at 6 cm;
- fingertips tilted 25 degrees forward at the grasp (`grasp_tilt`, `grasp_height=0.011` so the palm clears the
  peg, `final_tcp_x_max=0.55`, seeds 0-199): the hand ends 65 degrees from vertical, which the arm reaches
  further out, so the peg is carried less, but joint 6 then turns ~2.6 rad instead of ~1.6 rad: median 36,
  max 42.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from kitbench.geometry import axis_angle_to_matrix
from kitbench.planning.lift_peg_upright import LiftPegUprightBase, LiftPegUprightConfig
from kitbench.planning.phases import OPEN, Step, hold
from kitbench.planning.poses import HAND_DOWN, make_pose, rot_y, rot_z, upright_correction
from kitbench.tasks.lift_peg_upright import PEG_HALF_LENGTH, PEG_HALF_WIDTH


@dataclass(frozen=True, kw_only=True)
class PlannerConfig(LiftPegUprightConfig):
    """The Panda expert's tunables; the defaults are the measured best (module docstring)."""

    grasp_tilt: float = 0.0  # fingertips tilted forward (towards the peg's far end), rad
    grasp_offset: float = 0.0  # TCP along the peg's axis from its centre, m (negative: towards the robot)
    grasp_height: float = 0.0  # TCP above the peg's axis, m
    descend_height: float = 0.05
    turn_by: float = 0.6  # fraction of the approach curve by which the hand has turned to the grasp orientation
    final_tcp_x_max: float = 0.4  # base-frame x of the TCP with the peg upright (reach limit, see module doc)
    final_x_backoff: float = 0.03  # how much nearer the base to retry a swing the IK cannot follow, m
    speed_factor: float = 1.0  # fraction of the Panda's joint velocity and acceleration limits plans may use
    close_steps: int = 1  # the fingers close in one step
    # set down: at 4 mm all 200 recorded seeds end with the peg standing on the table (0.0 mm from its success
    # height in 30 checked)
    release_press: float = 0.004
    release_steps: int = 2


class LiftPegUprightPlanner(LiftPegUprightBase):
    """The LiftPegUpright-v1 expert for the Panda (module docstring); its public API is `PhasePlanner`'s."""

    cfg: PlannerConfig

    @classmethod
    def default_config(cls) -> PlannerConfig:
        return PlannerConfig()

    def peg_size(self) -> tuple[float, float]:
        return PEG_HALF_LENGTH, PEG_HALF_WIDTH  # the peg as the task builds it for the Panda

    # -- grasp ----------------------------------------------------------------------------------------------------
    def _peg_frame(self) -> np.ndarray:
        """The lying peg's frame: origin on the table under its centre, x along its axis pointing away from the
        robot (the end that will go down), z up."""
        peg = self._object_pose()
        axis = peg[:3, 0]
        if axis[0] < 0:
            axis = -axis
        return make_pose(rot_z(math.atan2(axis[1], axis[0])), [peg[0, 3], peg[1, 3], 0.0])

    def _grasp_pose(self) -> np.ndarray:
        c = self.cfg
        local = make_pose(rot_y(-c.grasp_tilt) @ HAND_DOWN, [self.grasp_offset, 0.0, self.half_width + c.grasp_height])
        return self._peg_frame() @ local

    def _approach_turn(self) -> float:
        return self.cfg.turn_by

    def _approach_handle(self, p0: np.ndarray, p2: np.ndarray, drop: float, lift_off: bool) -> np.ndarray:
        """Straight up first after a missed grasp; else a third of the way towards the descent."""
        return p0 + (np.array([0.0, 0.0, drop]) if lift_off else (p2 - p0) / 3.0)

    def _open_command(self) -> float:
        return OPEN

    def _plan_regrasp(self) -> list[Step]:
        """Open, then approach the peg where it is now, leaving straight up first."""
        opened = hold(self._last(), 1, gripper=OPEN, phase="regrasp")[0]
        approach = self._plan_approach(start=opened, lift_off=True)
        for step in approach:
            if step.phase == "approach" and step.tcp[2, 3] < opened.tcp[2, 3] + self.cfg.descend_height:
                step.phase = "regrasp"
            else:
                break
        return [opened, *approach]

    # -- swing ----------------------------------------------------------------------------------------------------
    def _swing_targets(self) -> Iterable[float]:
        """The TCP's base-frame x with the peg upright: as far out as the arm reaches, then nearer the base."""
        return (self.cfg.final_tcp_x_max - attempt * self.cfg.final_x_backoff for attempt in range(4))

    def _swing_path(self, peg: np.ndarray, tcp_in_peg: np.ndarray, target: float, start: np.ndarray):
        """The TCP pose along the swing as a function of s in [0, 1].

        The peg turns by s * 90 degrees about the horizontal axis across it, its far end going down. That end
        rises just enough to clear the table as the peg tilts (its lowest corner is the half-width times
        cos(angle) below the axis) plus `swing_lift` mid-way, travels back and ends under the goal,
        `set_down_clearance` above the table. The goal is as far forward as the arm reaches (`target`, the TCP's
        base-frame x), never further than the peg's own far end. Turn and travel are both linear in s: a profile
        that eases out (zero slope in s) would let the time parametrisation race through the nearly still end of
        the path.
        """
        c = self.cfg
        frame = self._peg_frame()
        forward, across = frame[:3, 0], frame[:3, 1]
        end0 = peg[:3, 3] + self.half_length * forward
        # With the peg upright the TCP sits at a fixed horizontal offset from the peg's axis: place the axis
        # so that the TCP lands at base-frame x = target (or turn in place if that is nearer).
        upright = axis_angle_to_matrix(across * (math.pi / 2)) @ peg[:3, :3]
        offset = upright @ tcp_in_peg[:3, 3]
        base_x_of_end0 = self.ik.to_base(make_pose(np.eye(3), end0 + offset))[0, 3]
        end1 = end0 - forward * max(0.0, base_x_of_end0 - target)
        end1[2] = self.set_down_clearance

        def pose_at(s: float) -> np.ndarray:
            angle = s * math.pi / 2
            turn = axis_angle_to_matrix(across * angle)
            end = end0 + s * (end1 - end0)
            end[2] = self.half_width * math.cos(angle) + c.swing_lift * math.sin(math.pi * s) + end1[2] * s
            centre = end - self.half_length * (turn @ forward)
            return make_pose(turn @ peg[:3, :3], centre) @ tcp_in_peg

        return pose_at

    # -- place ----------------------------------------------------------------------------------------------------
    def _peg_bottom(self, peg: np.ndarray, axis: np.ndarray) -> float:
        return peg[2, 3] - self.half_length  # upright within tilt_tolerance

    def _upright_correction(self, peg: np.ndarray, goal_height: float, tilt: float) -> np.ndarray:
        return upright_correction(peg, goal_height, tilt)  # the tilt as measured (`geometry.tilt_from_vertical`)


__all__ = ["LiftPegUprightPlanner", "PlannerConfig"]
