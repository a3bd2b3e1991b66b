"""The SO-101's expert for LiftPegUpright-v1 (its half-size peg, `kitbench.tasks.lift_peg_upright.ROBOT_SCALE`):
grasp the lying peg from above, off-centre towards its outer end, and swing it upright about its inner end.

Why this motion. Five joints reach a jaw pointing down anywhere in the peg's spawn square, at any roll, but a jaw
pointing level only 23 cm or more from the base and never below the wrist's limit (wrist_flex -95 degrees)
nearer in: a level jaw holding a vertical peg low is in reach at ~24.5 cm (`final_reach`). So the peg turns the
way the wrist lifts the jaw: its outer end rises, its inner end (nearer the base) stays low and travels out to
where the level jaw reaches, then stops `set_down_clearance` above the table with the peg vertical at its success
height. The peg is held `grasp_offset` towards its outer end so the jaw ends higher (a level jaw 6 cm above the
table is 4 mm out of reach at 24 cm; 9 cm up, 1 mm). The jaw's heading follows the arm's plane (five joints set
no other), so the hand at the end points along the radius through the goal, not along the peg's first axis.

The jaw is single-acting: the fixed jaw's face is the TCP, and the peg's axis ends up `PEG_HALF_WIDTH` beside it
along the TCP's y (towards the moving jaw), where the closing jaw presses it. The fixed jaw comes down
`fixed_jaw_clearance` away from the peg and the closing jaw pushes the peg onto it.

Phases (`planner.phase`): approach and descend, grasp (close, check, one retry), swing, place (re-aim the hand if
the peg turned in it), set_down, release, done, failed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from kitbench.geometry import tilt_from_vertical
from kitbench.planning.ik import TimedPath
from kitbench.planning.phases import CLOSED, OPEN, Step, hold, steps_from
from kitbench.planning.planner import DRIVE_LEAD, PhasePlanner, check_spread, drawn_within
from kitbench.planning.poses import cubic_bezier, interpolate_pose, make_pose, smoothstep, upright_correction
from kitbench.tasks.lift_peg_upright import PEG_HALF_LENGTH, PEG_HALF_WIDTH


@dataclass(frozen=True)
class PlannerConfig:
    """The expert's tunables; the defaults are the measured best (module docstring)."""

    # TCP along the peg's axis from its centre towards its outer end, fraction of the half-length
    grasp_offset: float = 0.3
    # each episode's grasp_offset is drawn uniformly within this of it (same unit): demonstrations that hold the peg
    # anywhere along it, as a learned grasp does, and set it down by where it is held (docs/studies/set-down.md)
    grasp_offset_spread: float = 0.0
    # the fixed jaw comes down this far beside the peg, not touching it: the closing jaw pushes the peg across onto
    # it, so a hand a few millimetres off (a learned policy's) still grasps instead of landing on the peg
    fixed_jaw_clearance: float = 0.006
    # TCP above the peg's axis: the fixed jaw's tip (23 mm below it) clears the table by 4 mm, m
    grasp_height: float = 0.015
    descend_height: float = 0.04  # the approach ends with a vertical descent from this high above the grasp, m
    final_reach: float = 0.265  # horizontal distance of the TCP from the base's origin with the peg upright, m
    reach_step: float = 0.01  # how much further out to retry a swing the IK cannot follow, m
    swing_lift: float = 0.01  # extra clearance of the peg's low end mid-swing, m
    set_down_clearance: float = 0.002  # peg bottom above the table at the end of the swing, m
    # each episode's set_down_clearance is drawn uniformly within this of it, m: the set-down's length varies, so
    # only the table ends it, as a learned swing that ends too high needs (docs/studies/set-down.md)
    set_down_clearance_spread: float = 0.0
    speed_factor: float = 0.5  # fraction of the servos' no-load speed and acceleration plans may use
    drive_lead: float = DRIVE_LEAD  # the commanded joints lead the plan by this share of the drives' lag
    # the jaw's command while open (1 fully, 100 degrees; -1 closed): wide open, the jaw's heel reaches the table
    # beside a low grasp; at 0.2 (gripper.pos 60, 56 degrees) it clears the 2.5 cm peg by 2 cm at the pads
    open_command: float = 0.2
    close_steps: int = 3  # ~2 steps to close on the peg from open_command
    settle_steps: int = 1
    max_grasp_attempts: int = 2
    height_tolerance: float = 0.003  # place: re-aim when the peg's centre is further than this from its goal, m
    tilt_tolerance: float = 0.04  # place: or when the peg leans more than this, rad
    max_correctable_tilt: float = 0.5  # place: give up on a peg leaning more than this in the hand, rad
    release_press: float = 0.003  # set down: the hand goes this far below the peg's contact height, m
    release_steps: int = 3  # release: open and wait for the jaw to leave the peg

    def __post_init__(self) -> None:
        check_spread("grasp_offset_spread", self.grasp_offset_spread)
        clearance = ("set_down_clearance", self.set_down_clearance)
        check_spread("set_down_clearance_spread", self.set_down_clearance_spread, clearance, "the table")


class SO101LiftPegUprightPlanner(PhasePlanner):
    """The LiftPegUpright-v1 expert for the SO-101 (module docstring); its public API is `PhasePlanner`'s.

    `failure` is None, "grasp", "ik", "dropped" or "tilted".
    """

    cfg: PlannerConfig
    phases = ("approach", "descend", "grasp", "regrasp", "swing", "place", "set_down", "release", "done", "failed")

    @classmethod
    def default_config(cls) -> PlannerConfig:
        return PlannerConfig()

    def on_reset(self) -> None:
        scale = self.env.peg_scale
        self.half_length, self.half_width = PEG_HALF_LENGTH * scale, PEG_HALF_WIDTH * scale
        self.grasp_offset = drawn_within(self.rng, self.cfg.grasp_offset, self.cfg.grasp_offset_spread)
        c = self.cfg
        self.set_down_clearance = drawn_within(self.rng, c.set_down_clearance, c.set_down_clearance_spread)

    # -- geometry -------------------------------------------------------------------------------------------------
    def _outward(self, peg: np.ndarray) -> np.ndarray:
        """The peg's axis, pointing away from the robot's base."""
        axis = peg[:3, 0].copy()
        axis[2] = 0.0
        axis /= max(float(np.linalg.norm(axis)), 1e-12)
        radial = peg[:3, 3] - self.ik.base[:3, 3]
        return axis if float(np.dot(axis, radial[:3])) >= 0 else -axis

    def _grasp_pose(self) -> np.ndarray:
        """Jaw pointing down, the fixed jaw's face along the peg, the peg's axis `half_width` along the TCP's y:
        of the two such poses (the jaw on either side), the one the wrist's roll reaches nearer where it is."""
        peg = self._object_pose()
        outward = self._outward(peg)
        down = np.array([0.0, 0.0, -1.0])
        best, best_cost = None, np.inf
        for x in (outward, -outward):
            y = np.cross(down, x)
            centre = peg[:3, 3] + self.grasp_offset * self.half_length * outward
            beside = self.half_width + self.cfg.fixed_jaw_clearance
            position = centre - beside * y + [0.0, 0.0, self.cfg.grasp_height]
            pose = make_pose(np.column_stack([x, y, down]), position)
            result = self.ik.solve_path([pose], self._last().q)
            cost = (
                result.position_error
                + 0.05 * result.rotation_error
                + 0.01 * float(np.abs(result.qs[-1] - self._last().q).sum())
            )
            if cost < best_cost:
                best, best_cost = pose, cost
        assert best is not None
        return best

    # -- phases ---------------------------------------------------------------------------------------------------
    def plan_next(self, finished: str | None) -> list[Step]:
        if finished is None:
            return self._plan_approach()
        if finished == "descend":
            return hold(self._last(), self.cfg.close_steps, gripper=CLOSED, phase="grasp")
        if finished == "grasp":
            if self._holding():
                return self._plan_swing()
            if self.grasp_attempts < self.cfg.max_grasp_attempts:
                return self._plan_regrasp()
            return self._fail("grasp")
        if finished == "set_down":
            return hold(self._last(), self.cfg.release_steps, gripper=OPEN, phase="release")
        if finished in ("release", "done"):
            return hold(self._last(), 1, gripper=OPEN, phase="done")
        if finished in ("swing", "place"):
            if not self._holding():
                return self._fail("dropped")
            return self._plan_place(again=finished == "place")
        return self._fail(self.failure or "unknown")

    def _plan_approach(self, start: Step | None = None) -> list[Step]:
        """A curve to `descend_height` above the grasp, turning the jaw on the way, then straight down."""
        self.grasp_attempts += 1
        start = start or self._last()
        grasp = self._grasp_pose()
        drop = self.cfg.descend_height
        p0, p3 = start.tcp[:3, 3], grasp[:3, 3]
        p2 = p3 + np.array([0.0, 0.0, drop])
        split = float(np.linalg.norm(p2 - p0) / (np.linalg.norm(p2 - p0) + drop))
        p1 = p0 + np.array([0.0, 0.0, max(0.0, p2[2] - p0[2])]) + (p2 - p0) / 3.0
        p1b = p2 + np.array([0.0, 0.0, drop * split / (3.0 * (1.0 - split))])

        def pose_at(s: float) -> np.ndarray:
            turned = interpolate_pose(start.tcp, grasp, smoothstep(s / (0.8 * split)))
            if s < split:
                position = cubic_bezier(p0, p1, p1b, p2, s / split)
            else:
                position = p2 + (p3 - p2) * (s - split) / (1.0 - split)
            return make_pose(turned[:3, :3], position)

        steps = steps_from(self._timed(pose_at, start, min_steps=3), self.cfg.open_command, "approach")
        for step in steps:
            if step.tcp[2, 3] < p2[2] - 1e-6 and np.linalg.norm(step.tcp[:2, 3] - p3[:2]) < 0.01:
                step.phase = "descend"
        steps[-1].phase = "descend"
        return steps

    def _plan_regrasp(self) -> list[Step]:
        """Open, rise, and approach the peg where it is now."""
        opened = hold(self._last(), 2, gripper=self.cfg.open_command, phase="regrasp")
        return [*opened, *self._plan_approach(start=opened[-1])]

    def _final_tcp(self, peg: np.ndarray, tcp_in_peg: np.ndarray, reach: float) -> np.ndarray:
        """The TCP with the peg upright (as it is held now), its bottom `set_down_clearance` above the table and
        the TCP `reach` from the base along the radius through the peg's centre, the jaw level along it."""
        base = self.ik.base[:3, 3]
        radial = peg[:3, 3] - base
        radial[2] = 0.0
        radial /= max(float(np.linalg.norm(radial)), 1e-12)
        up = np.array([0.0, 0.0, 1.0])
        # the peg's axis in the hand: x, turned by the grasp about the closing axis (y) by a little
        axis_in_tcp = np.linalg.inv(tcp_in_peg)[:3, 0]
        if axis_in_tcp[0] < 0:
            axis_in_tcp = -axis_in_tcp
        pitch = math.atan2(axis_in_tcp[2], axis_in_tcp[0])  # about the TCP's y
        # turning the jaw from down to level about the horizontal across the radius takes its x (along the peg,
        # pointing out or in) up or down: the outer end rises either way
        x = up if float(np.dot(self._tcp()[:3, 0], self._outward(peg))) >= 0 else -up
        nominal = np.column_stack([x, np.cross(radial, x), radial])  # z along the radius
        c, s = math.cos(pitch), math.sin(pitch)
        rotation = nominal @ np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
        tcp = make_pose(rotation, base + reach * radial)
        peg_after = tcp @ np.linalg.inv(tcp_in_peg)
        axis = peg_after[:3, 0] if peg_after[2, 0] >= 0 else -peg_after[:3, 0]
        bottom = peg_after[2, 3] - self.half_length * axis[2]
        tcp[2, 3] += self.set_down_clearance - bottom
        self.planned_tilt = tilt_from_vertical(axis)
        return tcp

    def _plan_swing(self) -> list[Step]:
        """Turn the held peg upright about its inner end while carrying it out to the level jaw's reach; retry
        further out if the IK cannot follow. The peg's pose in the hand is measured, not assumed."""
        start = self._last()
        peg = self._object_pose()
        tcp_in_peg = np.linalg.inv(peg) @ self._tcp()
        best: TimedPath | None = None
        for attempt in range(4):
            reach = self.cfg.final_reach + attempt * self.cfg.reach_step
            path = self._timed(self._swing_path(peg, tcp_in_peg, reach, start.tcp), start, min_steps=4)
            if best is None or path.ik.position_error < best.ik.position_error:
                best = path
            if path.ik.ok(position_tol=3e-3, rotation_tol=0.05):
                break
        assert best is not None
        if not best.ik.ok(position_tol=3e-3, rotation_tol=0.05):
            self.failure = "ik"
        steps = steps_from(best, CLOSED, "swing")
        return steps + hold(steps[-1], self.cfg.settle_steps)

    def _swing_path(self, peg: np.ndarray, tcp_in_peg: np.ndarray, reach: float, start: np.ndarray):
        """The TCP along the swing, s in [0, 1]: the hand turns from `start` to the final pose (shortest arc)
        while the peg's inner end travels from where it lies to under the goal, rising just enough to clear the
        table as the peg tilts, plus `swing_lift` mid-way."""
        c = self.cfg
        final = self._final_tcp(peg, tcp_in_peg, reach)
        peg_in_tcp = np.linalg.inv(tcp_in_peg)
        # the inner end (the peg's axis end nearer the base) in the hand's frame
        sign = -1.0 if float(np.dot(self._outward(peg), peg[:3, 0])) > 0 else 1.0
        end_local = peg_in_tcp[:3, :3] @ np.array([sign * self.half_length, 0.0, 0.0]) + peg_in_tcp[:3, 3]
        end0 = start[:3, :3] @ end_local + start[:3, 3]
        end1 = final[:3, :3] @ end_local + final[:3, 3]

        def pose_at(s: float) -> np.ndarray:
            turned = interpolate_pose(start, final, s)
            rotation = turned[:3, :3]
            axis = rotation @ peg_in_tcp[:3, 0]
            tilt = math.asin(min(1.0, abs(float(axis[2]))))
            end = end0 + s * (end1 - end0)
            end[2] = self.half_width * math.cos(tilt) + c.swing_lift * math.sin(math.pi * s) + end1[2] * s
            return make_pose(rotation, end - rotation @ end_local)

        return pose_at

    def _plan_place(self, again: bool) -> list[Step]:
        """Once the peg is upright at its goal height, set it down; if it turned in the hand, first move the hand
        by the correction that brings the peg, held as it is, upright at the goal height (once)."""
        start = self._last()
        peg = self._object_pose()
        axis = peg[:3, 0] if peg[2, 0] >= 0 else -peg[:3, 0]
        goal_height = self.half_length + self.set_down_clearance
        height_error = goal_height - peg[2, 3]
        tilt = tilt_from_vertical(axis)
        if again or (abs(height_error) <= self.cfg.height_tolerance and tilt <= self.cfg.tilt_tolerance):
            return self._plan_set_down(start, peg[2, 3] - self.half_length * axis[2])
        if tilt > self.cfg.max_correctable_tilt:
            return self._fail("tilted")
        target = upright_correction(peg, goal_height) @ start.tcp  # the hand moves with the peg it holds
        path = self._timed(lambda s: interpolate_pose(start.tcp, target, s), start, min_steps=2)
        return steps_from(path, CLOSED, "place")

    def _plan_set_down(self, start: Step, clearance: float) -> list[Step]:
        """Lower the upright peg onto the table, `release_press` past contact."""
        target = start.tcp.copy()
        target[2, 3] -= clearance + self.cfg.release_press
        path = self._timed(lambda s: interpolate_pose(start.tcp, target, s), start, min_steps=1)
        return steps_from(path, CLOSED, "set_down")


__all__ = ["PlannerConfig", "SO101LiftPegUprightPlanner"]
