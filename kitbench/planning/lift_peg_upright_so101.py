"""The SO-101's expert for LiftPegUpright-v1 (its half-size peg, `kitbench.tasks.lift_peg_upright.ROBOT_SCALE`),
the hooks of `lift_peg_upright.LiftPegUprightBase`: grasp the lying peg from above, off-centre towards its outer
end, and swing it upright about its inner end.

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
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from kitbench.geometry import tilt_from_vertical
from kitbench.planning.lift_peg_upright import LiftPegUprightBase, LiftPegUprightConfig
from kitbench.planning.phases import Step, hold
from kitbench.planning.poses import interpolate_pose, make_pose
from kitbench.tasks.lift_peg_upright import PEG_HALF_LENGTH, PEG_HALF_WIDTH


@dataclass(frozen=True, kw_only=True)
class PlannerConfig(LiftPegUprightConfig):
    """The SO-101 expert's tunables; the defaults are the measured best (module docstring)."""

    # TCP along the peg's axis from its centre towards its outer end, fraction of the half-length
    grasp_offset: float = 0.3
    # the fixed jaw comes down this far beside the peg, not touching it: the closing jaw pushes the peg across onto
    # it, so a hand a few millimetres off (a learned policy's) still grasps instead of landing on the peg
    fixed_jaw_clearance: float = 0.006
    # TCP above the peg's axis: the fixed jaw's tip (23 mm below it) clears the table by 4 mm, m
    grasp_height: float = 0.015
    descend_height: float = 0.04
    final_reach: float = 0.265  # horizontal distance of the TCP from the base's origin with the peg upright, m
    reach_step: float = 0.01  # how much further out to retry a swing the IK cannot follow, m
    speed_factor: float = 0.5  # fraction of the servos' no-load speed and acceleration plans may use
    # the jaw's command while open (1 fully, 100 degrees; -1 closed): wide open, the jaw's heel reaches the table
    # beside a low grasp; at 0.2 (gripper.pos 60, 56 degrees) it clears the 2.5 cm peg by 2 cm at the pads
    open_command: float = 0.2
    close_steps: int = 3  # ~2 steps to close on the peg from open_command
    release_press: float = 0.003
    release_steps: int = 3


class SO101LiftPegUprightPlanner(LiftPegUprightBase):
    """The LiftPegUpright-v1 expert for the SO-101 (module docstring); its public API is `PhasePlanner`'s."""

    cfg: PlannerConfig
    swing_tolerance = (3e-3, 0.05)
    place_once = True

    @classmethod
    def default_config(cls) -> PlannerConfig:
        return PlannerConfig()

    def peg_size(self) -> tuple[float, float]:
        scale = self.env.peg_scale
        return PEG_HALF_LENGTH * scale, PEG_HALF_WIDTH * scale

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

    def _approach_turn(self) -> float:
        return 0.8

    def _approach_handle(self, p0: np.ndarray, p2: np.ndarray, drop: float, lift_off: bool) -> np.ndarray:
        """A third of the way towards the descent, raised to its height first: the jaw starts low."""
        return p0 + np.array([0.0, 0.0, max(0.0, p2[2] - p0[2])]) + (p2 - p0) / 3.0

    def _open_command(self) -> float:
        return self.cfg.open_command

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

    def _swing_targets(self) -> Iterable[float]:
        """The TCP's horizontal distance from the base with the peg upright: the level jaw's reach, then further."""
        return (self.cfg.final_reach + attempt * self.cfg.reach_step for attempt in range(4))

    def _swing_path(self, peg: np.ndarray, tcp_in_peg: np.ndarray, target: float, start: np.ndarray):
        """The TCP along the swing, s in [0, 1]: the hand turns from `start` to the final pose (shortest arc)
        while the peg's inner end travels from where it lies to under the goal, rising just enough to clear the
        table as the peg tilts, plus `swing_lift` mid-way; `target`: the TCP's reach at the end (`_final_tcp`)."""
        c = self.cfg
        final = self._final_tcp(peg, tcp_in_peg, target)
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


__all__ = ["PlannerConfig", "SO101LiftPegUprightPlanner"]
