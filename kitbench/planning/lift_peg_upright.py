"""The LiftPegUpright-v1 expert every robot that grasps the lying peg from above shares: approach and descend,
close and check the grasp (one retry), swing the held peg upright, re-aim it if it turned in the hand, set it down
on the table and let go. Each robot supplies the motion itself through the hooks below (`lift_peg_upright_panda`,
`lift_peg_upright_so101`); its config sets the shared tunables' measured defaults and adds its own. Fetch, which
grasps the peg's end from behind and lets it hang, has a planner of its own (`lift_peg_upright_fetch`).

Phases (`planner.phase`): approach and descend (one smooth motion ending in a vertical descent), grasp (close,
check, one retry via regrasp), swing (lift, turn, carry and set down in one motion), place (re-aim the hand if
the peg slipped or turned in it), set_down (onto the table), release (open), done (keep still), failed.
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from kitbench.geometry import tilt_from_vertical
from kitbench.planning.ik import TimedPath
from kitbench.planning.phases import CLOSED, OPEN, Step, hold, steps_from
from kitbench.planning.planner import DRIVE_LEAD, PhasePlanner, check_spread, drawn_within
from kitbench.planning.poses import cubic_bezier, interpolate_pose, make_pose, smoothstep, upright_correction


@dataclass(frozen=True, kw_only=True)
class LiftPegUprightConfig:
    """The tunables the robots' experts share; those without a default are set by each robot's config."""

    grasp_offset: float  # TCP along the peg's axis from its centre (each robot's config says which way and unit)
    # each episode's grasp_offset is drawn uniformly within this of it (same unit): demonstrations that hold the peg
    # anywhere along it, as a learned grasp does, and set it down by where it is held (docs/studies/set-down.md)
    grasp_offset_spread: float = 0.0
    grasp_height: float  # TCP above the peg's axis, m
    descend_height: float  # the approach ends with a vertical descent from this high above the grasp, m
    swing_lift: float = 0.01  # extra clearance of the peg's low end mid-swing, m
    set_down_clearance: float = 0.002  # peg bottom above the table at the end of the swing, m
    # each episode's set_down_clearance is drawn uniformly within this of it, m: the set-down's length varies, so
    # only the table ends it, as a learned swing that ends too high needs (docs/studies/set-down.md)
    set_down_clearance_spread: float = 0.0
    speed_factor: float  # fraction of the robot's joint velocity and acceleration limits plans may use
    drive_lead: float = DRIVE_LEAD  # the commanded joints lead the plan by this share of the drives' lag
    close_steps: int  # gripper closing before the grasp is checked
    settle_steps: int = 1  # hold at the end of the swing before measuring the peg
    max_grasp_attempts: int = 2
    height_tolerance: float = 0.003  # place: re-aim when the peg's centre is further than this from its goal, m
    tilt_tolerance: float = 0.04  # place: or when the peg leans more than this, rad
    max_correctable_tilt: float = 0.5  # place: give up on a peg leaning more than this in the hand, rad
    release_press: float  # set down: the hand goes this far below the peg's contact height, m
    release_steps: int  # release: open and wait for the fingers to leave the peg

    def __post_init__(self) -> None:
        check_spread("grasp_offset_spread", self.grasp_offset_spread)
        clearance = ("set_down_clearance", self.set_down_clearance)
        check_spread("set_down_clearance_spread", self.set_down_clearance_spread, clearance, "the table")


class LiftPegUprightBase(PhasePlanner):
    """The phases (module docstring) around a robot's hooks; its public API is `PhasePlanner`'s.

    `failure` is None, "grasp", "ik", "dropped" or "tilted".
    """

    cfg: LiftPegUprightConfig
    phases = ("approach", "descend", "grasp", "regrasp", "swing", "place", "set_down", "release", "done", "failed")
    # the IK's position (m) and rotation (rad) errors within which a swing counts as followed
    swing_tolerance: ClassVar[tuple[float, float]] = (2e-3, 2e-2)
    # whether a peg still off its goal after one re-aim is set down as it is (else re-aimed again)
    place_once: ClassVar[bool] = False

    # -- hooks ----------------------------------------------------------------------------------------------------
    @abstractmethod
    def peg_size(self) -> tuple[float, float]:
        """The peg's half-length and half-width the motion is planned for, m."""

    @abstractmethod
    def _grasp_pose(self) -> np.ndarray:
        """The world TCP pose that grasps the lying peg (reads `grasp_offset`, this episode's draw)."""

    @abstractmethod
    def _approach_turn(self) -> float:
        """The fraction of the approach's curve by which the hand has turned to the grasp orientation."""

    @abstractmethod
    def _approach_handle(self, p0: np.ndarray, p2: np.ndarray, drop: float, lift_off: bool) -> np.ndarray:
        """The approach curve's first Bezier handle, from its start `p0` to `p2`, `drop` above the grasp; with
        `lift_off` the hand starts low, next to the peg."""

    @abstractmethod
    def _open_command(self) -> float:
        """The gripper's command while open."""

    @abstractmethod
    def _plan_regrasp(self) -> list[Step]:
        """After a missed grasp: open and approach the peg where it is now (`_plan_approach`)."""

    @abstractmethod
    def _swing_targets(self) -> Iterable[float]:
        """Where the swing ends, first choice first (a reach or a base-frame x, the robot's `_swing_path` says):
        each is tried in turn until the IK follows the swing."""

    @abstractmethod
    def _swing_path(
        self, peg: np.ndarray, tcp_in_peg: np.ndarray, target: float, start: np.ndarray
    ) -> Callable[[float], np.ndarray]:
        """The TCP pose along the swing as a function of s in [0, 1], from `start`, the peg held as `tcp_in_peg`
        says, ending at `target` (one of `_swing_targets`)."""

    def _peg_bottom(self, peg: np.ndarray, axis: np.ndarray) -> float:
        """The height of the held peg's low end, `axis` its axis pointing up."""
        return peg[2, 3] - self.half_length * axis[2]

    def _upright_correction(self, peg: np.ndarray, goal_height: float, tilt: float) -> np.ndarray:
        """The world transform that stands the held peg upright at `goal_height` (`poses.upright_correction`)."""
        return upright_correction(peg, goal_height)

    # -- episode --------------------------------------------------------------------------------------------------
    def on_reset(self) -> None:
        self.half_length, self.half_width = self.peg_size()
        self.grasp_offset = drawn_within(self.rng, self.cfg.grasp_offset, self.cfg.grasp_offset_spread)
        c = self.cfg
        self.set_down_clearance = drawn_within(self.rng, c.set_down_clearance, c.set_down_clearance_spread)

    def plan_next(self, finished: str | None) -> list[Step]:
        if finished is None:
            return self._plan_approach()
        if finished == "descend":
            return hold(self._last(), self.cfg.close_steps, gripper=CLOSED, phase="grasp")
        if finished == "grasp":
            if self._holding():
                return self._plan_swing()
            if self.grasp_attempts < self.cfg.max_grasp_attempts:
                return self._plan_regrasp()  # its steps run on into the next descent
            return self._fail("grasp")
        if finished == "set_down":  # the peg stands on the table by itself
            return hold(self._last(), self.cfg.release_steps, gripper=OPEN, phase="release")
        if finished in ("release", "done"):
            return hold(self._last(), 1, gripper=OPEN, phase="done")
        if finished in ("swing", "place"):
            if not self._holding():
                return self._fail("dropped")
            return self._plan_place(again=finished == "place")
        return self._fail(self.failure or "unknown")

    # -- phases ---------------------------------------------------------------------------------------------------
    def _plan_approach(self, start: Step | None = None, lift_off: bool = False) -> list[Step]:
        """One smooth motion to the grasp: a curve that turns the hand on the way and arrives vertically above the
        grasp, then a straight vertical descent, so the fingers come down beside the peg without stopping above
        it. The curve's end tangent matches the descent's speed along the path parameter, so the joint path has
        no kink for the time parametrisation to brake at."""
        self.grasp_attempts += 1
        start = start or self._last()
        grasp = self._grasp_pose()
        p0, p3 = start.tcp[:3, 3], grasp[:3, 3]
        drop = self.cfg.descend_height
        p2 = p3 + np.array([0.0, 0.0, drop])
        split = float(np.linalg.norm(p2 - p0) / (np.linalg.norm(p2 - p0) + drop))  # s at which the descent starts
        p1 = self._approach_handle(p0, p2, drop, lift_off)
        p1b = p2 + np.array([0.0, 0.0, drop * split / (3.0 * (1.0 - split))])
        turn_by = self._approach_turn()

        def pose_at(s: float) -> np.ndarray:
            turned = interpolate_pose(start.tcp, grasp, smoothstep(s / (turn_by * split)))
            if s < split:
                position = cubic_bezier(p0, p1, p1b, p2, s / split)
            else:
                position = p2 + (p3 - p2) * (s - split) / (1.0 - split)
            return make_pose(turned[:3, :3], position)

        steps = steps_from(self._timed(pose_at, start, min_steps=3), self._open_command(), "approach")
        for step in steps:
            if step.tcp[2, 3] < p2[2] - 1e-6 and np.linalg.norm(step.tcp[:2, 3] - p3[:2]) < 0.01:
                step.phase = "descend"
        steps[-1].phase = "descend"
        return steps

    def _plan_swing(self) -> list[Step]:
        """Turn the held peg upright, trying each of `_swing_targets` until the IK follows. The peg's pose in the
        hand is measured, not assumed."""
        start = self._last()
        peg = self._object_pose()
        tcp_in_peg = np.linalg.inv(peg) @ self._tcp()
        best: TimedPath | None = None
        for target in self._swing_targets():
            path = self._timed(self._swing_path(peg, tcp_in_peg, target, start.tcp), start, min_steps=4)
            if best is None or path.ik.position_error < best.ik.position_error:
                best = path
            if path.ik.ok(*self.swing_tolerance):
                break
        assert best is not None
        if not best.ik.ok(*self.swing_tolerance):
            self.failure = "ik"
        steps = steps_from(best, CLOSED, "swing")
        return steps + hold(steps[-1], self.cfg.settle_steps)

    def _plan_place(self, again: bool) -> list[Step]:
        """Once the peg is upright at its goal height, set it down. If it has slipped or turned in the hand, first
        move the hand by the correction that would bring the peg, held as it is now, upright at the goal height
        (`again`: this is the second look, after a correction)."""
        start = self._last()
        peg = self._object_pose()
        axis = peg[:3, 0] if peg[2, 0] >= 0 else -peg[:3, 0]
        goal_height = self.half_length + self.set_down_clearance
        height_error = goal_height - peg[2, 3]
        tilt = tilt_from_vertical(axis)
        on_goal = abs(height_error) <= self.cfg.height_tolerance and tilt <= self.cfg.tilt_tolerance
        if on_goal or (again and self.place_once):
            return self._plan_set_down(start, self._peg_bottom(peg, axis))
        if tilt > self.cfg.max_correctable_tilt:
            return self._fail("tilted")
        target = self._upright_correction(peg, goal_height, tilt) @ start.tcp  # the hand moves with the peg it holds
        path = self._timed(lambda s: interpolate_pose(start.tcp, target, s), start, min_steps=2)
        return steps_from(path, CLOSED, "place")

    def _plan_set_down(self, start: Step, clearance: float) -> list[Step]:
        """Lower the upright peg onto the table, the hand `release_press` past contact so that the table, not the
        hand, fixes the peg's height (the fingers slip that far along the peg at most)."""
        target = start.tcp.copy()
        target[2, 3] -= clearance + self.cfg.release_press
        path = self._timed(lambda s: interpolate_pose(start.tcp, target, s), start, min_steps=1)
        return steps_from(path, CLOSED, "set_down")


__all__ = ["LiftPegUprightBase", "LiftPegUprightConfig"]
