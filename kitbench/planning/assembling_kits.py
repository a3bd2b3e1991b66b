"""Expert for AssemblingKits-v1: pick the loose shape from above, carry it over its slot turned to the goal yaw,
re-aim from the measured pose of the shape, lower it in and let go.

Why this motion. The pockets leave 0.69-2 mm per side (kits/clearance.py: as much as lets no shape sit in its
pocket turned 3.5 degrees), so the shape must arrive within a fraction of a millimetre and a degree: what matters
is where the *shape* is, not the hand. The shape's pose in the hand is measured after the lift and every later
target is the shape's goal pose composed with that measured grasp; just above the slot the shape's pose is
measured again and the hand corrected (up to three times) until the shape is within 0.75 degrees and 40% of its
pocket's clearance (at most 1.5 mm) before it goes down.

Grasp: from straight above, through the shape's centroid, closing across its narrowest width (`ShapeGeometry.
grasp_angle`), the fingertips 1.2 cm above the surface the shape rests on, so that seated in its 1 cm deep pocket
the fingertips still clear the board. Among closing directions, those whose fingers come down and close clear of
the seated shapes (or, on the table, of the board) come first: checking only where the open fingertips come down,
2 of 500 grasps closed a finger onto a seated shape (seeds 115, 214). Wrist: the hand can close along the grasp
direction two ways (yaw phi or phi + pi) and the shape can be seated at any yaw equivalent under its symmetry;
among these the planner takes the pair needing the least total wrist rotation that keeps joint 7 inside its
limits, turning the shortest way or the long way round as the limits require (an asymmetric shape may need up to
180 degrees).

Grip: once the shape is held the fingers are driven 5 mm past where they stopped (~5 N each), not fully shut. Fully
shut (a target 1 cm past closed, ~30 N each) they sank 1-6 mm into the shape's hulls, the grasp chattered in a
two-step cycle (0.5-0.9 mm at the shape's bottom, 1.5-3 degrees of tilt: more than the hexagon's 0.69 mm pocket
allows) and 4 of 500 shapes slid out of the hand during the lift or the transport.

Every motion is timed as fast as the Panda's joint velocity and acceleration limits allow (`ik.ArmIK.plan`);
the final descent into the pocket runs at a quarter of that.

Measured (`bench/expert_assembling_kits.py`, seeds 0-499, pd_joint_pos): 499/500 (99.8%), steps over successes
median 44, p90 54, max 71 of 200; every shape at 100% but the house (20/21: at seed 487 the open fingers come
down on a seated shape in every direction that fits). With the uniform 2 mm pockets and the fully shut grip it
was 495/500; the per-shape pockets with that grip, 492/500 (docs/kit-physics.md).

The SO-101 (`SO101_CONFIG`, its kits at 0.7 scale): one jaw fixed to the hand, so its face goes onto the shape's
outline (against a face of the shape where there is one) and the moving jaw presses the shape against it; a
five-joint wrist, whose roll the planner budgets counting the arm's swing about its base and whose hand stays
straight down; servos that lag their targets under load, which the align and insert moves aim out, aligning once
more just above the board. Measured (`--robot so101`, held-out seeds 10000-10299, pd_joint_pos): 281/300 (93.7%),
median 67 steps, max 133 of 200 (docs/robots.md).

Phases (`planner.phase`): approach, descend, grasp (close, check; one retry via regrasp), lift, transport, align
(measure and re-aim over the slot), insert, release, retreat, failed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from kitbench.geometry import (
    axis_angle_to_matrix,
    matrix_to_axis_angle,
    planar_yaw,
    wrap_angle,
)
from kitbench.kits.fingers import CLEAR_ENOUGH, Pad, fingertip_clearance, pick_obstacles, seated_outlines
from kitbench.kits.shapes import place
from kitbench.planning.kit_grasps import (
    JawContact,
    across_narrowest,
    closing_widths,
    grip_period,
    jaw_contacts,
    signed_yaw_options,
)
from kitbench.planning.phases import CLOSED, OPEN, Step, hold, steps_from
from kitbench.planning.planner import DRIVE_LEAD, MEASURED_DELTA_TRACKING, PhasePlanner
from kitbench.planning.poses import HAND_DOWN, make_pose, rot_z
from kitbench.tasks.assembling_kits import yaw_error


@dataclass(frozen=True)
class AssemblingKitsPlannerConfig:
    """The expert's tunables."""

    grasp_height: float = 0.022  # TCP above the shape's bottom face at the grasp, m
    approach_height: float = 0.06  # the descent to the grasp starts this high above it, m
    carry_clearance: float = 0.03  # shape bottom above the board top while carried, m
    release_height: float = 0.0005  # shape bottom above the pocket floor when the fingers open, m
    joint7_margin: float = 0.1  # rad kept from joint 7's limits
    clear_enough: float = CLEAR_ENOUGH  # m between a fingertip and an obstacle beyond which more does not matter
    align_position_tolerance: float = 0.0015  # m: re-aim over the slot when the shape is further off
    align_yaw_tolerance: float = math.radians(0.75)  # rad: or turned further than this
    # ...or further off than this fraction of its pocket's clearance (0.69-2 mm per side, kits/clearance.py): a turn
    # within the yaw tolerance uses up to a fifth of the clearance, which leaves the rest to the position.
    align_clearance_fraction: float = 0.4
    max_align_corrections: int = 3
    insert_speed: float = 0.25  # fraction of the joint limits for the descent into the pocket
    close_steps: int = 2
    settle_steps: int = 2  # still steps before a measurement
    release_steps: int = 3
    retreat_height: float = 0.05
    max_grasp_attempts: int = 2
    # Once the shape is held, the fingers are driven this far (m, each) past where they stopped, not fully shut;
    # None: fully shut.
    grip_squeeze: float | None = 0.005
    speed_factor: float = 1.0
    drive_lead: float = DRIVE_LEAD  # the commanded joints lead the plan by this share of the drives' lag
    # In the measured end-effector delta modes, each joint moves at most this share of the action bound a step
    # (None: at the joint limits): faster, the hand falls behind its plan and the shape reaches its slot still
    # turning (docs/fidelity.md, "The experts under ManiSkill's gains").
    ee_delta_tracking: float | None = MEASURED_DELTA_TRACKING
    max_opening: float = 0.07  # m, the widest grasp the planner uses (the Panda opens 8 cm)
    open_command: float = OPEN  # the gripper command of an open hand (1: fully open)
    # Whether the planner counts the hand's turn by the arm's swing about its base against the wrist's limits: a
    # five-joint arm's downward hand turns with its shoulder pan one to one (the Panda's seven joints share it).
    wrist_follows_pan: bool = False
    # Whether the align and insert moves aim the hand's command, not the hand: arms whose joints lag their targets
    # under load (position servos without gravity compensation) leave the hand a few millimetres short of every
    # target, so re-aiming at the measured error must move the command by that error.
    aim_by_command: bool = False
    # Whether the hand levels a shape it holds tilted before lowering it in: a seven-joint arm can tilt its hand any
    # way; a five-joint arm's downward hand cannot tilt across its arm's plane, and keeps its hand straight down.
    level_held: bool = True
    # A fixed jaw (RobotSpec.fixed_jaw) prefers a face at least this wide (m): pushed against a corner, a shape turns
    # in the jaw.
    min_jaw_face: float = 0.006
    # The hand's pads (kits.fingers.Pad, TCP frame) where they differ from the Panda's fingertips around the centroid.
    jaw_pads: tuple[Pad, ...] | None = None
    # Clearance (m) from obstacles that counts as clear, before the fixed jaw's face is weighed.
    clear_first: float = 0.004
    # Where set (m): the shape is lowered to this far above the board's top and aligned there again before it goes
    # in, for a hand whose lag changes as the arm folds down (the SO-101's drifted 1-2 mm over a 2 cm descent).
    pre_insert_height: float | None = None
    # Whether the grasp closes across the shape's narrowest width (`ShapeGeometry.grasp_angle`, up to the shape's
    # symmetry) wherever the fingers come down that way as clear as `clear_first`: the shape's yaw in the hand is then
    # one value per shape in most episodes, so the turn to its slot is the slot's yaw less the hand's, which a policy
    # reads from pixels and joints; closing any way, it has to read the shape's own yaw
    # (docs/studies/assembling-kits-pixels-turn.md, "One grip per shape").
    prefer_narrowest: bool = False
    # Whether the carry goes over the slot unturned and the shape is turned there, in place, at `turn_speed` (a
    # fraction of the joint limits): the turn is then made where the cameras see the held shape beside its slot, one
    # relation in the picture rather than two yaws read apart
    # (docs/studies/assembling-kits-pixels-turn.md, "Turning the shape over its slot").
    turn_over_slot: bool = False
    turn_speed: float = 0.5


# The SO-101's (kitbench/robots/so101.py), for its kit at 0.7 scale (shapes 2.1 cm tall, standing 1.4 cm proud of
# the board when seated): its TCP is 23 mm from the jaw's tip, so 3 cm above the shape's bottom keeps the tip 7 mm up;
# carried 2 cm above the board and approached from 4 cm above the grasp, the hand stays low enough for its wrist to
# point straight down over the whole kit (higher, the wrist flex ran into its 95-degree limit near the base). Its
# jaw opens to 56 degrees (gripper.pos 60) and squeezes 0.05 rad past where it stopped (0.1 or more squeezes the
# pointed shapes out of the jaw), after 5 steps to close (its servo sweeps ~40 degrees). Its servos run at half their
# no-load speed and lag their targets by 1-3 mm under load, which the align and insert moves aim out; the wrist's
# turn is predicted from the arm's swing to within ~0.15 rad, hence the wider margin from its limits (docs/robots.md
# has what each setting bought).
SO101_CONFIG = AssemblingKitsPlannerConfig(
    grasp_height=0.03,
    approach_height=0.04,
    carry_clearance=0.02,
    grip_squeeze=0.05,
    close_steps=5,
    speed_factor=0.5,
    max_opening=0.05,
    open_command=0.2,
    wrist_follows_pan=True,
    joint7_margin=0.25,
    aim_by_command=True,
    level_held=False,
    pre_insert_height=0.002,
    # the fixed jaw's lowest part, 2.6 cm behind its face and 2.3 cm wide, reaches 7 mm above the shape's bottom (below
    # the board's top beside a shape on the table); the moving jaw's comes down within 5 cm ahead of it as it closes
    jaw_pads=((-0.026, 0.0, 0.0115), (0.0, 0.05, 0.011)),
)
ROBOT_CONFIGS = {"so101": SO101_CONFIG}


class AssemblingKitsPlanner(PhasePlanner):
    """The AssemblingKits-v1 expert (module docstring); its public API is `PhasePlanner`'s.

    `failure` is None, "grasp", "ik" or "dropped".
    """

    cfg: AssemblingKitsPlannerConfig
    phases = (
        "approach",
        "descend",
        "grasp",
        "regrasp",
        "lift",
        "transport",
        "align",
        "insert",
        "release",
        "retreat",
        "failed",
    )

    def __init__(self, env, config: AssemblingKitsPlannerConfig | None = None):
        super().__init__(env, config)
        self.fixed_jaw = self.env.robot_spec.fixed_jaw
        # the wrist roll: the arm's last joint, which turns a downward hand about the vertical, one to one
        self.wrist = self.n_arm - 1
        q = self.env.robot.arm_qpos().astype(np.float64)
        turned = q.copy()
        turned[self.wrist] += 0.1
        self.wrist_sign = float(
            np.sign(wrap_angle(planar_yaw(self.ik.fk(turned)[:3, :3]) - planar_yaw(self.ik.fk(q)[:3, :3])))
        )

    @classmethod
    def default_config(cls) -> AssemblingKitsPlannerConfig:
        return AssemblingKitsPlannerConfig()

    @classmethod
    def robot_config(cls, robot_uid: str) -> AssemblingKitsPlannerConfig:
        return ROBOT_CONFIGS.get(robot_uid) or cls.default_config()

    def on_reset(self) -> None:
        self.align_corrections = 0
        self.grip = CLOSED  # the gripper command that holds the shape
        self.turn_at_goal = 0.0  # signed rotation of the shape from its pose at the grasp to the goal, rad

    @property
    def q7_limits(self) -> np.ndarray:
        """The wrist roll's (lower, upper) limits, rad (the Panda's joint 7): the wrist turn the grasp and the goal
        yaw must fit in."""
        return self.ik.limits[self.wrist]

    # -- paths ----------------------------------------------------------------------------------------------------
    def _move(
        self,
        start: Step,
        target: np.ndarray,
        turn: float,
        gripper: float,
        phase: str,
        speed: float = 1.0,
        min_steps: int = 2,
    ) -> list[Step]:
        """A straight TCP move to `target` turning the hand by `turn` rad about the vertical (signed: the long
        way round when joint 7 needs it), any residual tilt spread along the way."""
        a = start.tcp
        turned = rot_z(turn) @ a[:3, :3]
        residual = matrix_to_axis_angle(turned.T @ target[:3, :3])

        def pose_at(s: float) -> np.ndarray:
            rotation = rot_z(s * turn) @ a[:3, :3] @ axis_angle_to_matrix(s * residual)
            return make_pose(rotation, (1 - s) * a[:3, 3] + s * target[:3, 3])

        path = self._timed(pose_at, start, min_steps=min_steps, speed=speed)
        if not path.ik.ok(position_tol=4e-3, rotation_tol=4e-2):
            self.failure = self.failure or "ik"
        return steps_from(path, gripper, phase)

    def _joint7_after(self, start: Step, turn: float, xy: np.ndarray) -> float:
        """The wrist roll after turning the (downward) hand by `turn` about the vertical on the way to `xy`: the
        two are locked 1:1 (the Panda's joint 7 with opposite signs: its axis points down along the hand), less
        what the arm's swing about its base turns the hand (`wrist_follows_pan`)."""
        return float(start.q[self.wrist] + self.wrist_sign * (turn - self._pan_turn(start.tcp[:2, 3], xy)))

    def _pan_turn(self, a: np.ndarray, b: np.ndarray) -> float:
        """How far the hand turns about the vertical when the arm swings from over `a` to over `b` (world xy):
        the change of their bearing from the base, for an arm whose shoulder pan turns its hand as much as its
        wrist does (`wrist_follows_pan`); 0 where the planner leaves that to IK (the Panda's seven joints)."""
        if not self.cfg.wrist_follows_pan:
            return 0.0
        base = self.ik.base[:2, 3]
        da, db = np.asarray(a) - base, np.asarray(b) - base
        return wrap_angle(math.atan2(db[1], db[0]) - math.atan2(da[1], da[0]))

    def _q7_ok(self, q7: float) -> bool:
        lo, hi = self.q7_limits
        return lo + self.cfg.joint7_margin <= q7 <= hi - self.cfg.joint7_margin

    # -- phases ---------------------------------------------------------------------------------------------------
    def plan_next(self, finished: str | None) -> list[Step]:
        if finished is None:
            return self._plan_approach()
        if finished == "descend":
            return hold(self._last(), self.cfg.close_steps, gripper=CLOSED, phase="grasp")
        if finished == "grasp":
            if self._holding():
                self.grip = self._grip_command()
                return self._plan_lift()
            if self.grasp_attempts < self.cfg.max_grasp_attempts:
                return self._plan_regrasp()
            return self._fail("grasp")
        if finished == "lift":
            if not self._holding():
                return (
                    self._plan_regrasp() if self.grasp_attempts < self.cfg.max_grasp_attempts else self._fail("dropped")
                )
            return self._plan_transport()
        if finished in ("transport", "align"):
            if not self._holding():
                return self._fail("dropped")
            return self._plan_align()
        if finished == "insert":
            return hold(self._last(), self.cfg.release_steps, gripper=self.cfg.open_command, phase="release")
        if finished == "release":
            target = self._last().tcp.copy()
            target[2, 3] += self.cfg.retreat_height
            return self._move(self._last(), target, 0.0, self.cfg.open_command, "retreat")
        return self._fail(self.failure or "done") if finished != "retreat" else hold(self._last(), 1, phase="retreat")

    def _choose_grasp(self, start: Step) -> tuple[float, float]:
        """(hand turn to the grasp, shape turn to the goal), both signed.

        Over closing directions (through the centroid, opening at most `max_opening`), the two hand yaws that
        close along each, and the goal yaws equivalent under the shape's symmetry: keep the wrist roll inside its
        limits at the grasp and at the goal; prefer a fixed jaw (RobotSpec.fixed_jaw) against a face, then fingers
        clear of obstacles (up to `clear_enough`) where they come down and close at the grasp and where they come
        down beside the slot, then the least wrist rotation, then the narrowest opening."""
        obj = self._object_pose()
        obj_yaw = planar_yaw(obj[:3, :3])
        shape = self.env.shape
        hand_yaw = planar_yaw(start.tcp[:3, :3])
        delta = wrap_angle(self.env.goal_rot - obj_yaw)
        rotations = signed_yaw_options(delta, shape.symmetry)
        episode = self.env.episode
        around = pick_obstacles(episode, self.env.episodes.board, float(obj[2, 3]))
        seated = seated_outlines(episode, shape.scale)
        goal_xy = self.env.goal_pos[:2]
        best = None
        widths = closing_widths(shape.shape_id, shape.scale)
        contacts = jaw_contacts(shape.shape_id, shape.scale)
        for (angle, opening), contact in zip(widths, contacts, strict=True):
            if opening > self.cfg.max_opening:
                continue
            closing = obj_yaw + angle
            narrowest = self.cfg.prefer_narrowest and across_narrowest(angle, shape.grasp_angle, shape.symmetry)
            base = wrap_angle(closing + math.pi / 2 - hand_yaw)  # hand yaw whose fingers close along `closing`
            # clearances by the fixed jaw's side (None for hands whose pads do not depend on it), then rotation
            pick_clear: dict[bool | None, float] = {}
            goal_clear: dict[tuple[float, bool | None], float] = {}
            for rotation in rotations:
                for m in (-2, -1, 0, 1, 2):
                    turn = base + m * math.pi
                    q7 = self._joint7_after(start, turn, obj[:2, 3])
                    at_goal = q7 + self.wrist_sign * (rotation - self._pan_turn(obj[:2, 3], goal_xy))
                    if not (self._q7_ok(q7) and self._q7_ok(at_goal)):
                        continue
                    # which way the hand's y (towards the moving jaw) points along `closing`: a fixed jaw's side
                    jaw_y = (rot_z(turn) @ start.tcp[:3, :3])[:2, 1]
                    ahead = float(jaw_y @ [math.cos(closing), math.sin(closing)]) < 0
                    side = ahead if self.cfg.jaw_pads is not None else None
                    if side not in pick_clear:
                        pick_clear[side] = self._clearance(obj[:2, 3], closing, 0.0, contact, ahead, around, True)
                    if (rotation, side) not in goal_clear:
                        goal_clear[rotation, side] = self._clearance(
                            goal_xy, closing, rotation, contact, ahead, seated, False
                        )
                    clear = round(min(pick_clear[side], goal_clear[rotation, side], self.cfg.clear_enough), 3)
                    face = 0.0
                    if self.fixed_jaw:
                        face = round(
                            min(contact.ahead_face if ahead else contact.behind_face, self.cfg.min_jaw_face), 3
                        )
                    key = (
                        min(clear, self.cfg.clear_first),
                        narrowest,
                        face,
                        clear,
                        -(abs(turn) + abs(rotation)) - 5.0 * opening,
                    )
                    if best is None or key > best[0]:
                        best = (key, turn, rotation)
        if best is None:  # no direction fits the opening or joint 7: fall back on the narrowest, shortest way
            return wrap_angle(obj_yaw + shape.grasp_angle + math.pi / 2 - hand_yaw), delta
        return best[1], best[2]

    def _clearance(
        self,
        xy: np.ndarray,
        closing: float,
        rotation: float,
        contact: JawContact,
        ahead: bool,
        obstacles: list,
        swept: bool,
    ) -> float:
        """How clear of `obstacles` (m) the hand comes down (and, `swept`, closes) over a shape whose centroid is at
        `xy`, turned by `rotation` from where it closes along `closing`: the Panda's fingertips around the centroid,
        or the hand's own `jaw_pads` from its TCP (a fixed jaw's on the outline, behind the shape along its y, or
        ahead when `ahead`)."""
        pads = self.cfg.jaw_pads
        if pads is None:
            return fingertip_clearance(xy, closing + rotation, obstacles, swept=swept)
        y = closing + rotation + (math.pi if ahead else 0.0)  # the hand's y, along which its pads lie
        # the TCP from the centroid along y (<= 0): a fixed jaw's face where it meets the outline
        offset = (-contact.ahead_at if ahead else contact.behind_at) if self.fixed_jaw else 0.0
        tcp = np.asarray(xy) + offset * np.array([math.cos(y), math.sin(y)])
        return fingertip_clearance(tcp, y, obstacles, pads=pads)

    def _plan_approach(self, start: Step | None = None) -> list[Step]:
        self.grasp_attempts += 1
        start = start or self._last()
        turn, self.turn_at_goal = self._choose_grasp(start)
        obj = self._object_pose()
        rotation = rot_z(turn) @ start.tcp[:3, :3]
        rotation = rot_z(planar_yaw(rotation)) @ HAND_DOWN  # exactly downward, at the chosen yaw
        xy = obj[:2, 3] + self._jaw_offset(obj, rotation[:2, 1])
        grasp = make_pose(rotation, [xy[0], xy[1], obj[2, 3] + self.cfg.grasp_height])
        above = grasp.copy()
        above[2, 3] += self.cfg.approach_height
        opened = self.cfg.open_command
        steps = self._move(start, above, turn, opened, "approach")
        steps += self._move(steps[-1], grasp, 0.0, opened, "descend")
        return steps

    def _jaw_offset(self, obj: np.ndarray, closing: np.ndarray) -> np.ndarray:
        """Where the TCP goes from the shape's centroid (xy): nowhere for two fingers closing on it together; for a
        fixed jaw (its face is the TCP, `closing` its TCP y, towards the moving jaw), onto the shape's outline
        where the fixed jaw's face meets it, so that the moving jaw presses the shape against it unmoved."""
        if not self.fixed_jaw:
            return np.zeros(2)
        outline = place(self.env.shape.outline, 0.0, 0.0, planar_yaw(obj[:3, :3]))
        points = np.asarray(outline.exterior.coords)
        return float(np.min(points @ closing)) * closing

    def _plan_regrasp(self) -> list[Step]:
        opened = hold(self._last(), 1, gripper=self.cfg.open_command, phase="regrasp")
        up = opened[0].tcp.copy()
        up[2, 3] += 0.03
        steps = opened + self._move(opened[0], up, 0.0, self.cfg.open_command, "regrasp")
        return steps + self._plan_approach(steps[-1])

    def _grip_command(self) -> float:
        """The gripper command (-1 closed .. 1 open) that drives the fingers `grip_squeeze` past where they hold the
        shape now."""
        if self.cfg.grip_squeeze is None:
            return CLOSED
        spec = self.env.robot_spec
        # one finger joint's position: half a parallel gripper's opening, or a single jaw's angle
        target = self.env.robot.gripper_opening() / len(spec.finger_joints) - self.cfg.grip_squeeze
        fraction = (target - spec.finger_closed) / (spec.finger_open - spec.finger_closed)
        return float(np.clip(2.0 * fraction - 1.0, CLOSED, OPEN))

    def _carry_z(self, obj: np.ndarray, tcp: np.ndarray) -> float:
        """TCP height that carries the shape's bottom `carry_clearance` above the board top."""
        board_top = self.env.episodes.board.top
        return board_top + self.cfg.carry_clearance + (tcp[2, 3] - obj[2, 3])

    def _plan_lift(self) -> list[Step]:
        start = self._last()
        target = start.tcp.copy()
        target[2, 3] = self._carry_z(self._object_pose(), self._tcp())
        return self._move(start, target, 0.0, self.grip, "lift")

    def _goal_tcp(self, obj: np.ndarray, tcp: np.ndarray, rotation: float, shape_bottom_z: float) -> np.ndarray:
        """The TCP pose that puts the shape, held as it is now, flat, turned by `rotation` about the vertical, over
        its goal with its bottom at `shape_bottom_z`. A shape held a few degrees tilted is levelled here: released
        tilted, it would turn as it settles (its measured yaw is that of its tilted axis)."""
        yaw = planar_yaw(obj[:3, :3]) + rotation
        goal = make_pose(rot_z(yaw), [self.env.goal_pos[0], self.env.goal_pos[1], shape_bottom_z])
        if self.cfg.level_held:
            return goal @ (np.linalg.inv(obj) @ tcp)
        # the hand straight down, turned by `rotation`, holding the shape where it holds it now (its tilt kept)
        offset = rot_z(rotation)[:2, :2] @ (tcp[:2, 3] - obj[:2, 3])
        hand = rot_z(planar_yaw(tcp[:3, :3]) + rotation) @ HAND_DOWN
        position = [goal[0, 3] + offset[0], goal[1, 3] + offset[1], shape_bottom_z + tcp[2, 3] - obj[2, 3]]
        return make_pose(hand, position)

    def _aimed(self, start: Step, desired: np.ndarray, tcp: np.ndarray) -> np.ndarray:
        """The command that brings the hand to `desired`: itself, or (`aim_by_command`) moved by how far the hand
        now stands from its last command (in the hand's frame, its turn too), a lag that holds while the load does."""
        if not self.cfg.aim_by_command:
            return desired
        return desired @ np.linalg.inv(tcp) @ self.ik.fk(start.q)

    def _plan_transport(self) -> list[Step]:
        """Carry the shape over its slot, turning it to the goal yaw (on the way, or with `turn_over_slot` there, in
        place), measured: the turn is recomputed from the shape's yaw now (it may have turned in the hand), keeping
        the direction chosen at the grasp unless the wrist's limits no longer allow it."""
        start = self._last()
        obj, tcp = self._object_pose(), self._tcp()
        delta = wrap_angle(self.env.goal_rot - planar_yaw(obj[:3, :3]))
        options = sorted(signed_yaw_options(delta, self.env.shape.symmetry), key=lambda r: abs(r - self.turn_at_goal))
        pan = self._pan_turn(tcp[:2, 3], self.env.goal_pos[:2])
        fits = [r for r in options if self._q7_ok(start.q[self.wrist] + self.wrist_sign * (r - pan))]
        rotation = (fits or options)[0]
        carry_bottom = self.env.episodes.board.top + self.cfg.carry_clearance
        target = self._goal_tcp(obj, tcp, rotation, carry_bottom)
        if self.cfg.turn_over_slot:
            over = self._move(start, self._goal_tcp(obj, tcp, 0.0, carry_bottom), 0.0, self.grip, "transport")
            steps = over + self._move(over[-1], target, rotation, self.grip, "transport", speed=self.cfg.turn_speed)
        else:
            steps = self._move(start, target, rotation, self.grip, "transport")
        return steps + hold(steps[-1], self.cfg.settle_steps)

    def _plan_align(self) -> list[Step]:
        """Measure the shape over the slot; re-aim the hand if it is off, else lower it in."""
        start = self._last()
        obj, tcp = self._object_pose(), self._tcp()
        obj_yaw = planar_yaw(obj[:3, :3])
        yaw_off = yaw_error(obj_yaw, self.env.goal_rot, self.env.shape.symmetry)
        xy_off = float(np.linalg.norm(self.env.goal_pos[:2] - obj[:2, 3]))
        clearance = self.env.episodes.board.clearance[self.env.shape.shape_id]
        xy_tolerance = min(self.cfg.align_position_tolerance, self.cfg.align_clearance_fraction * clearance)
        if (xy_off > xy_tolerance or yaw_off > self.cfg.align_yaw_tolerance) and (
            self.align_corrections < self.cfg.max_align_corrections
        ):
            self.align_corrections += 1
            delta = wrap_angle(self.env.goal_rot - obj_yaw)
            rotation = min(signed_yaw_options(delta, self.env.shape.symmetry), key=abs)
            target = self._aimed(start, self._goal_tcp(obj, tcp, rotation, obj[2, 3]), tcp)
            steps = self._move(start, target, rotation, self.grip, "align")
            return steps + hold(steps[-1], self.cfg.settle_steps)
        low = self.cfg.pre_insert_height
        board_top = self.env.episodes.board.top
        if low is not None and obj[2, 3] > board_top + low + 0.002:  # not yet down there: lower, then align again
            self.align_corrections = 0
            target = self._aimed(start, self._goal_tcp(obj, tcp, 0.0, board_top + low), tcp)
            steps = self._move(start, target, 0.0, self.grip, "align", speed=self.cfg.insert_speed)
            return steps + hold(steps[-1], self.cfg.settle_steps)
        floor = self.env.floor
        target = self._aimed(start, self._goal_tcp(obj, tcp, 0.0, floor + self.cfg.release_height), tcp)
        return self._move(start, target, 0.0, self.grip, "insert", speed=self.cfg.insert_speed)


__all__ = [
    "AssemblingKitsPlanner",
    "AssemblingKitsPlannerConfig",
    "across_narrowest",
    "grip_period",
    "signed_yaw_options",
]
