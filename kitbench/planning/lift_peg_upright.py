"""Expert for LiftPegUpright-v1: grasp the lying peg from above and swing it upright, held, onto the table.

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

Phases (`planner.phase`): approach and descend (one smooth motion ending in a vertical descent), grasp (close,
check, one retry via regrasp), swing (lift, turn, carry and set down in one motion), place (re-aim the
hand if the peg slipped or turned in it), set_down (onto the table), release (open), done (keep still), failed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from kitbench.geometry import axis_angle_to_matrix, tilt_from_vertical
from kitbench.planning.ik import TimedPath
from kitbench.planning.phases import CLOSED, OPEN, Step, hold, steps_from
from kitbench.planning.planner import DRIVE_LEAD, PhasePlanner, check_spread, drawn_within
from kitbench.planning.poses import (
    HAND_DOWN,
    cubic_bezier,
    interpolate_pose,
    make_pose,
    rot_y,
    rot_z,
    smoothstep,
)
from kitbench.tasks.lift_peg_upright import PEG_HALF_LENGTH, PEG_HALF_WIDTH


@dataclass(frozen=True)
class PlannerConfig:
    """The expert's tunables; the defaults are the measured best (module docstring)."""

    grasp_tilt: float = 0.0  # fingertips tilted forward (towards the peg's far end), rad
    grasp_offset: float = 0.0  # TCP along the peg's axis from its centre, m (negative: towards the robot)
    # each episode's grasp_offset is drawn uniformly within this of it, m: demonstrations that hold the peg anywhere
    # along it, as a learned grasp does, and set it down by where it is held (docs/studies/set-down.md)
    grasp_offset_spread: float = 0.0
    grasp_height: float = 0.0  # TCP above the peg's axis, m
    descend_height: float = 0.05  # the approach ends with a vertical descent from this high above the grasp, m
    turn_by: float = 0.6  # fraction of the approach curve by which the hand has turned to the grasp orientation
    final_tcp_x_max: float = 0.4  # base-frame x of the TCP with the peg upright (reach limit, see module doc)
    final_x_backoff: float = 0.03  # how much nearer the base to retry a swing the IK cannot follow, m
    swing_lift: float = 0.01  # extra clearance of the peg's low end mid-swing, m
    set_down_clearance: float = 0.002  # peg bottom above the table at the end of the swing, m
    # each episode's set_down_clearance is drawn uniformly within this of it, m: the set-down's length varies, so
    # only the table ends it, as a learned swing that ends too high needs (docs/studies/set-down.md)
    set_down_clearance_spread: float = 0.0
    speed_factor: float = 1.0  # fraction of the Panda's joint velocity and acceleration limits plans may use
    drive_lead: float = DRIVE_LEAD  # the commanded joints lead the plan by this share of the drives' lag
    close_steps: int = 1  # gripper closing before the grasp is checked (the fingers close in one step)
    settle_steps: int = 1  # hold at the end of the swing before measuring the peg
    max_grasp_attempts: int = 2
    height_tolerance: float = 0.003  # place: re-aim when the peg's centre is further than this from its goal, m
    tilt_tolerance: float = 0.04  # place: or when the peg leans more than this, rad
    max_correctable_tilt: float = 0.5  # place: give up on a peg leaning more than this in the hand, rad
    # set down: the hand goes this far below the peg's contact height, m; at 4 mm all 200 recorded seeds end with
    # the peg standing on the table (0.0 mm from its success height in 30 checked)
    release_press: float = 0.004
    release_steps: int = 2  # release: open and wait for the fingers to leave the peg

    def __post_init__(self) -> None:
        check_spread("grasp_offset_spread", self.grasp_offset_spread)
        clearance = ("set_down_clearance", self.set_down_clearance)
        check_spread("set_down_clearance_spread", self.set_down_clearance_spread, clearance, "the table")


class LiftPegUprightPlanner(PhasePlanner):
    """The LiftPegUpright-v1 expert (module docstring); its public API is `PhasePlanner`'s.

    `failure` is None, "grasp", "ik", "dropped" or "tilted".
    """

    cfg: PlannerConfig
    phases = ("approach", "descend", "grasp", "regrasp", "swing", "place", "set_down", "release", "done", "failed")

    @classmethod
    def default_config(cls) -> PlannerConfig:
        return PlannerConfig()

    def on_reset(self) -> None:
        self.grasp_offset = drawn_within(self.rng, self.cfg.grasp_offset, self.cfg.grasp_offset_spread)
        c = self.cfg
        self.set_down_clearance = drawn_within(self.rng, c.set_down_clearance, c.set_down_clearance_spread)

    # -- state ----------------------------------------------------------------------------------------------------
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
        local = make_pose(rot_y(-c.grasp_tilt) @ HAND_DOWN, [self.grasp_offset, 0.0, PEG_HALF_WIDTH + c.grasp_height])
        return self._peg_frame() @ local

    # -- phases ---------------------------------------------------------------------------------------------------
    def plan_next(self, finished: str | None) -> list[Step]:
        if finished is None:
            return self._plan_approach()
        if finished == "descend":
            return self._plan_close()
        if finished == "grasp":
            if self._holding():
                return self._plan_swing()
            if self.grasp_attempts < self.cfg.max_grasp_attempts:
                return self._plan_regrasp()  # its steps run on into the next descent
            return self._fail("grasp")
        if finished == "set_down":
            return self._plan_release()
        if finished in ("release", "done"):
            return hold(self._last(), 1, gripper=OPEN, phase="done")
        if finished in ("swing", "place"):
            if not self._holding():
                return self._fail("dropped")
            return self._plan_place()
        return self._fail(self.failure or "unknown")

    def _plan_approach(self, start: Step | None = None, lift_off: bool = False) -> list[Step]:
        """One smooth motion to the grasp: a curve that turns the hand on the way and arrives vertically above the
        grasp, then a straight vertical descent, so the fingers come down on either side of the peg (1.5 cm of
        clearance each) without stopping above it. The curve's end tangent matches the descent's speed along
        the path parameter, so the joint path has no kink for the time parametrisation to brake at. With
        `lift_off` the curve also leaves straight up (the hand starts low, next to the peg)."""
        self.grasp_attempts += 1
        start = start or self._last()
        grasp = self._grasp_pose()
        p0, p3 = start.tcp[:3, 3], grasp[:3, 3]
        drop = self.cfg.descend_height
        p2 = p3 + np.array([0.0, 0.0, drop])
        split = float(np.linalg.norm(p2 - p0) / (np.linalg.norm(p2 - p0) + drop))  # s at which the descent starts
        p1 = p0 + (np.array([0.0, 0.0, drop]) if lift_off else (p2 - p0) / 3.0)
        p1b = p2 + np.array([0.0, 0.0, drop * split / (3.0 * (1.0 - split))])

        def pose_at(s: float) -> np.ndarray:
            turned = interpolate_pose(start.tcp, grasp, smoothstep(s / (self.cfg.turn_by * split)))
            if s < split:
                position = cubic_bezier(p0, p1, p1b, p2, s / split)
            else:
                position = p2 + (p3 - p2) * (s - split) / (1.0 - split)
            return make_pose(turned[:3, :3], position)

        path = self._timed(pose_at, start, min_steps=3)
        steps = steps_from(path, OPEN, "approach")
        for step in steps:
            if step.tcp[2, 3] < p2[2] - 1e-6 and np.linalg.norm(step.tcp[:2, 3] - p3[:2]) < 0.01:
                step.phase = "descend"
        steps[-1].phase = "descend"
        return steps

    def _plan_close(self) -> list[Step]:
        return hold(self._last(), self.cfg.close_steps, gripper=CLOSED, phase="grasp")

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

    def _plan_swing(self) -> list[Step]:
        """Turn the held peg upright about its far end, carrying it back into reach; retry nearer the base if
        the IK cannot follow. The peg's pose in the hand is measured, not assumed."""
        start = self._last()
        peg = self._object_pose()
        tcp_in_peg = np.linalg.inv(peg) @ self._tcp()
        best: TimedPath | None = None
        for attempt in range(4):
            x_max = self.cfg.final_tcp_x_max - attempt * self.cfg.final_x_backoff
            path = self._timed(self._swing_path(peg, tcp_in_peg, x_max), start, min_steps=4)
            if best is None or path.ik.position_error < best.ik.position_error:
                best = path
            if path.ik.ok():
                break
        assert best is not None
        if not best.ik.ok():
            self.failure = "ik"
        steps = steps_from(best, CLOSED, "swing")
        return steps + hold(steps[-1], self.cfg.settle_steps)

    def _swing_path(self, peg: np.ndarray, tcp_in_peg: np.ndarray, x_max: float):
        """The TCP pose along the swing as a function of s in [0, 1].

        The peg turns by s * 90 degrees about the horizontal axis across it, its far end going down. That end
        rises just enough to clear the table as the peg tilts (its lowest corner is PEG_HALF_WIDTH * cos(angle)
        below the axis) plus `swing_lift` mid-way, travels back and ends under the goal, `set_down_clearance`
        above the table. The goal is as far forward as the arm reaches (`x_max`), never further than the peg's
        own far end. Turn and travel are both linear in s: a profile that eases out (zero slope in s) would let
        the time parametrisation race through the nearly still end of the path.
        """
        c = self.cfg
        frame = self._peg_frame()
        forward, across = frame[:3, 0], frame[:3, 1]
        end0 = peg[:3, 3] + PEG_HALF_LENGTH * forward
        # With the peg upright the TCP sits at a fixed horizontal offset from the peg's axis: place the axis
        # so that the TCP lands at base-frame x = x_max (or turn in place if that is nearer).
        upright = axis_angle_to_matrix(across * (math.pi / 2)) @ peg[:3, :3]
        offset = upright @ tcp_in_peg[:3, 3]
        base_x_of_end0 = self.ik.to_base(make_pose(np.eye(3), end0 + offset))[0, 3]
        end1 = end0 - forward * max(0.0, base_x_of_end0 - x_max)
        end1[2] = self.set_down_clearance

        def pose_at(s: float) -> np.ndarray:
            angle = s * math.pi / 2
            turn = axis_angle_to_matrix(across * angle)
            end = end0 + s * (end1 - end0)
            end[2] = PEG_HALF_WIDTH * math.cos(angle) + c.swing_lift * math.sin(math.pi * s) + end1[2] * s
            centre = end - PEG_HALF_LENGTH * (turn @ forward)
            return make_pose(turn @ peg[:3, :3], centre) @ tcp_in_peg

        return pose_at

    def _plan_place(self) -> list[Step]:
        """Once the peg is upright at its goal height, set it down. If it has slipped or turned in the hand, first
        move the hand by the correction that would bring the peg, held as it is now, upright at the goal height."""
        start = self._last()
        peg = self._object_pose()
        axis = peg[:3, 0] if peg[2, 0] >= 0 else -peg[:3, 0]
        height_error = PEG_HALF_LENGTH + self.set_down_clearance - peg[2, 3]
        tilt = tilt_from_vertical(axis)
        if abs(height_error) <= self.cfg.height_tolerance and tilt <= self.cfg.tilt_tolerance:
            return self._plan_set_down(start, peg[2, 3] - PEG_HALF_LENGTH)
        if tilt > self.cfg.max_correctable_tilt:
            return self._fail("tilted")
        rotvec = np.cross(axis, [0.0, 0.0, 1.0])
        rotvec *= tilt / max(float(np.linalg.norm(rotvec)), 1e-12)
        goal = make_pose(axis_angle_to_matrix(rotvec) @ peg[:3, :3], peg[:3, 3] + [0.0, 0.0, height_error])
        correction = goal @ np.linalg.inv(peg)  # applied to the peg, and to the hand holding it
        target = correction @ start.tcp  # the hand moves with the peg: same world transform
        path = self._timed(lambda s: interpolate_pose(start.tcp, target, s), start, min_steps=2)
        return steps_from(path, CLOSED, "place")

    def _plan_set_down(self, start: Step, clearance: float) -> list[Step]:
        """Lower the upright peg onto the table, the hand `release_press` past contact so that the table, not the
        hand, fixes the peg's height (the fingers slip that far along the peg at most)."""
        target = start.tcp.copy()
        target[2, 3] -= clearance + self.cfg.release_press
        path = self._timed(lambda s: interpolate_pose(start.tcp, target, s), start, min_steps=1)
        return steps_from(path, CLOSED, "set_down")

    def _plan_release(self) -> list[Step]:
        """Open the hand and keep it still: the peg stands on the table by itself."""
        return hold(self._last(), self.cfg.release_steps, gripper=OPEN, phase="release")


__all__ = ["LiftPegUprightPlanner", "PlannerConfig"]
