"""Fetch's expert for LiftPegUpright-v1: grasp the peg's near end from behind, lift it and let it hang upright.

Why this motion. Fetch's base stands 1.05 m behind the table's centre: with the torso up, a top-down grasp is
reachable only for x <= -0.3 (the peg's centre lies in [-0.1, 0.1]), so the Panda's top-down centre grasp is out
of reach. A hand pointing forward reaches the peg's near end (x0 - 0.12), pitched `grasp_pitch` down so the
wrist clears the table; the fingers close across the peg (along y) a few centimetres onto its end. The swing
then turns the hand by the rest of 90 degrees, to point straight down, so the peg hangs below it, far end down,
while the hand rises and carries the peg back to where a downward-pointing hand is in reach (`final_x`); the
far end clears the table all the way and stops `set_down_clearance` above it, the peg at its success height.

Timing: every motion is timed as fast as Fetch's joint velocity and acceleration limits allow
(`ik.ArmIK.plan`). This motion does not fit the task's 50 control steps: both halves turn the wrist by about
two radians (wrist_flex from the folded ready pose, +2.08 rad, to ~0 at the grasp and back to ~+1.6 with the
hand down), each at least ~1.8 s (36 steps) at the real arm's 2.5 rad/s^2, and the shoulder lift (1.0 rad/s,
1.0 rad/s^2) lifts the arm out and back. Measured over seeds 0-499 (`bench/expert_lift_peg.py --robot fetch
--seeds 500 --max-steps 250`) within the real arm's limits (`kitbench.robots.fetch`): `pd_joint_pos` 500/500,
median 121 steps, p90 131, max 138; `pd_joint_delta_pos` 500/500, median 128, p90 137, max 145. With the looser
limits first assumed (3 rad/s^2, shoulder lift 1.454 rad/s): median 96 / 109, max 109 / 121. The task gives
Fetch 170 steps (`LiftPegUprightEnv.robot_max_episode_steps`). The alternatives below were timed under those
first limits; their order does not depend on them.
Measured alternatives, steps from the ready pose (rest to rest, pegs at x0 in {-0.1, 0, 0.1}):
- approach, hand horizontal (pitch 0): 59-64 steps as a Cartesian line, 39-45 as a joint-space line; pitched
  0.3 / 0.6 rad down: 49-56 / 41-47 Cartesian, 36-42 / 34-37 joint-space (so: joint space, 0.6 rad);
- swing to a hand pointing down at x = -0.30 / -0.35 / -0.40: 36-62 steps, shortest from the 0.6 rad grasp; but
  with the 0.6 rad grasp the hand ends tilted 0.6 rad back from vertical, its wrist 0.17 m further out, and
  only x <= -0.5 is reached for every peg (`final_x` -0.45: 15/20 seeds, the rest "ik"; -0.55: median +2 steps);
- a pitch of 0.8 rad (`grasp_height` 0.015 so the fingertips clear the table): the grasp is out of reach
  (0/20, "ik"); 0.45 rad: median 104 steps; 0.7 rad: 19/20, median 109;
- grasp depth 0.025 m and the peg's far end 2 mm above the table: the peg turns up to 6.5 degrees in the grasp
  during the swing and its tilted corner drags on the table (35/40); 0.03 m and 4 mm: 100/100, the peg turns
  0.7-4 degrees;
- a downward-pointing hand at the peg itself: out of reach (0.1-0.3 m short);
- driving the base 0.28 m forward (as far as the table allows) for a top-down grasp (reach measured, not
  simulated): reach ends at x ~0, short
  of pegs at x0 > 0 with a centre grasp, and the Panda-style swing (hand ending horizontal, pointing back) still
  turns the wrist by 90 degrees.

Phases (`planner.phase`): approach and insert (one smooth motion ending in a straight push along the hand's
axis onto the peg's end), grasp (close, check), swing (lift, turn, carry back), place (re-aim the hand once if
the peg turned in it), done (keep still), failed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from kitbench.geometry import axis_angle_to_matrix, tilt_from_vertical
from kitbench.planning.phases import CLOSED, OPEN, Step, hold, steps_from
from kitbench.planning.planner import DRIVE_LEAD, PhasePlanner
from kitbench.planning.poses import interpolate_pose, make_pose, rot_y, rot_z, upright_correction
from kitbench.tasks.lift_peg_upright import PEG_HALF_LENGTH, PEG_HALF_WIDTH

# The TCP pointing forward (+x), fingers closing along y: its axes as columns (x down, y along y, z forward).
HAND_FORWARD = np.column_stack([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])


@dataclass(frozen=True)
class PlannerConfig:
    """The expert's tunables; the defaults are the measured best (module docstring)."""

    grasp_pitch: float = 0.6  # hand pitched down from horizontal at the grasp, rad
    grasp_depth: float = 0.03  # TCP this far onto the peg from its end (the palm is 0.032 behind the TCP), m
    grasp_height: float = 0.008  # TCP above the peg's axis: the pitched fingertips clear the table, m
    insert_distance: float = 0.08  # the approach ends with a straight push along the hand's axis this long, m
    approach_share: float = 0.9  # share of the approach's path parameter on the joint-space line (0.8: +1.5 steps)
    final_x: float = -0.5  # world x of the TCP at the end of the swing at most (downward-hand reach), m
    swing_lift: float = 0.02  # extra clearance of the peg's far end mid-swing, m
    set_down_clearance: float = 0.004  # far end above the table at the end of the swing, m
    speed_factor: float = 1.0  # fraction of Fetch's joint velocity and acceleration limits plans may use
    drive_lead: float = DRIVE_LEAD  # the commanded joints lead the plan by this share of the drives' lag
    height_tolerance: float = 0.003  # place: re-aim when the peg's centre is further than this from its goal, m
    tilt_tolerance: float = 0.03  # place: or when it leans more than this, rad (success allows 0.08)
    close_steps: int = 2  # the fingers travel 0.1 -> 0.053 m in the first step and touch the peg in the second
    settle_steps: int = 2  # hold at the end of the swing before measuring the peg


class FetchLiftPegUprightPlanner(PhasePlanner):
    """The LiftPegUpright-v1 expert for Fetch (module docstring); its public API is `PhasePlanner`'s.

    `failure` is None, "grasp", "ik" or "dropped".
    """

    cfg: PlannerConfig
    phases = ("approach", "insert", "grasp", "swing", "place", "done", "failed")

    @classmethod
    def default_config(cls) -> PlannerConfig:
        return PlannerConfig()

    # -- state ----------------------------------------------------------------------------------------------------
    def _peg_frame(self) -> np.ndarray:
        """The lying peg's frame: origin at its centre, x along its axis pointing away from the robot, z up."""
        peg = self._object_pose()
        axis = peg[:3, 0] if peg[0, 0] >= 0 else -peg[:3, 0]
        return make_pose(rot_z(math.atan2(axis[1], axis[0])), peg[:3, 3])

    def _grasp_pose(self) -> np.ndarray:
        c = self.cfg
        local = make_pose(rot_y(c.grasp_pitch) @ HAND_FORWARD, [c.grasp_depth - PEG_HALF_LENGTH, 0.0, c.grasp_height])
        return self._peg_frame() @ local

    # -- phases ---------------------------------------------------------------------------------------------------
    def plan_next(self, finished: str | None) -> list[Step]:
        if finished is None:
            return self._plan_approach()
        if finished == "insert":
            return hold(self._last(), self.cfg.close_steps, gripper=CLOSED, phase="grasp")
        if finished == "grasp":
            return self._plan_swing() if self._holding() else self._fail("grasp")
        if finished in ("swing", "place"):
            return self._plan_place() if self._holding() else self._fail("dropped")
        if finished == "done":
            return hold(self._last(), 1, phase="done")
        return self._fail(self.failure or "unknown")

    def _plan_approach(self) -> list[Step]:
        """A straight line in joint space to the pre-grasp pose behind the peg's end, on the hand's axis, then a
        straight push along that axis onto the end, in one timed motion. The joint-space line is what the
        joint limits time fastest: 34-37 steps to the grasp against 41-47 for a Cartesian line (module doc)."""
        self.grasp_attempts += 1
        start = self._last()
        grasp = self._grasp_pose()
        pre = grasp.copy()
        pre[:3, 3] -= self.cfg.insert_distance * grasp[:3, 2]
        line = self.ik.solve_path([interpolate_pose(start.tcp, pre, s) for s in np.linspace(0.1, 1.0, 10)], start.q)
        q_pre = line.qs[-1]
        split = self.cfg.approach_share

        def pose_at(s: float) -> np.ndarray:
            if s < split:
                return self.ik.fk(start.q + (q_pre - start.q) * (s / split))
            return interpolate_pose(pre, grasp, (s - split) / (1.0 - split))

        path = self._timed(pose_at, start, min_steps=3)
        if not (line.ok() and path.ik.ok()):
            self.failure = "ik"
        steps = steps_from(path, OPEN, "approach")
        for step in steps:
            if float(np.dot(step.tcp[:3, 3] - pre[:3, 3], grasp[:3, 2])) > -1e-3:
                step.phase = "insert"
        steps[-1].phase = "insert"
        return steps

    def _plan_swing(self) -> list[Step]:
        """Turn the held peg upright, far end down, carrying it back into reach. The peg's pose in the hand is
        measured, not assumed."""
        start = self._last()
        peg = self._object_pose()
        tcp_in_peg = np.linalg.inv(peg) @ self._tcp()
        path = self._timed(self._swing_path(peg, tcp_in_peg), start, min_steps=4)
        if not path.ik.ok():
            self.failure = "ik"
        steps = steps_from(path, CLOSED, "swing")
        return steps + hold(steps[-1], self.cfg.settle_steps)

    def _swing_path(self, peg: np.ndarray, tcp_in_peg: np.ndarray):
        """The TCP pose along the swing, s in [0, 1]: the peg turns by s * 90 degrees about the axis across it
        (far end down); its centre rises just enough for the far end's lowest corner to clear the table (plus
        `swing_lift` mid-way) and travels back so that the TCP ends at world x <= `final_x`, the peg's centre at
        its success height. Turn and travel are linear in s (an eased profile lets the timing race the ends)."""
        c = self.cfg
        frame = self._peg_frame()
        forward, across = frame[:3, 0], frame[:3, 1]
        upright = axis_angle_to_matrix(across * (math.pi / 2)) @ peg[:3, :3]
        offset = upright @ tcp_in_peg[:3, 3]  # TCP from the peg's centre, the peg upright
        centre0 = peg[:3, 3]
        centre1 = centre0 - forward * max(0.0, centre0[0] + offset[0] - c.final_x)
        z1 = PEG_HALF_LENGTH + c.set_down_clearance

        def pose_at(s: float) -> np.ndarray:
            angle = s * math.pi / 2
            turn = axis_angle_to_matrix(across * angle)
            centre = centre0 + s * (centre1 - centre0)
            low = PEG_HALF_LENGTH * math.sin(angle) + PEG_HALF_WIDTH * math.cos(angle)  # far corner below centre
            centre[2] = max(centre0[2], low + c.set_down_clearance * s) + c.swing_lift * math.sin(math.pi * s)
            if s >= 1.0:
                centre[2] = z1
            return make_pose(turn @ peg[:3, :3], centre) @ tcp_in_peg

        return pose_at

    def _plan_place(self) -> list[Step]:
        """Re-aim the hand once if the peg ended the swing tilted or off its height, then keep still. The peg
        turns 0.6-3.4 degrees in the grasp during the swing (13 seeds); most episodes succeed before this runs,
        with the peg 0.04-0.075 rad from vertical."""
        start = self._last()
        peg = self._object_pose()
        goal_height = PEG_HALF_LENGTH + self.cfg.set_down_clearance
        tilt = tilt_from_vertical(peg[:3, 0] if peg[2, 0] >= 0 else -peg[:3, 0])
        on_target = abs(peg[2, 3] - goal_height) <= self.cfg.height_tolerance and tilt <= self.cfg.tilt_tolerance
        if on_target or self.phase == "place":
            return hold(start, 1, phase="done")
        target = upright_correction(peg, goal_height) @ start.tcp  # the hand moves with the peg
        path = self._timed(lambda s: interpolate_pose(start.tcp, target, s), start, min_steps=2)
        return steps_from(path, CLOSED, "place")


__all__ = ["FetchLiftPegUprightPlanner", "PlannerConfig"]
