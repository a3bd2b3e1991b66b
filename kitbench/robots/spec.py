"""`RobotSpec`: everything that distinguishes one robot from another, as data the generic `Robot` (the articulation
in a scene), `ArmKinematics` (its MuJoCo twin for IK) and the env read. A robot is one module under
`kitbench/robots/` that builds its specs; nothing else in kitbench names a robot's joints or links.

Action layout, whatever the robot: `[arm part (the control mode's), gripper, body joints..., base...]`: the arm
part is the control mode's (one value per arm joint, 3 or 6 TCP values), the gripper one value (-1 closed .. 1
open, ManiSkill's), then one delta per body joint (a head, a torso: position-driven joints outside the arm,
+-`body_action_bound` a step) and, for a mobile base, its forward velocity and yaw rate. A Panda has neither body
joints nor a base. A robot whose `units` are a real arm's shows its joints and gripper in those
(`kitbench.robots.units`); the simulation converts at the env's boundary.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from kitbench.robots.units import SI, JointUnits
from kitbench.sim.cameras import CameraSpec

# The gripper command of every robot's action, ManiSkill's convention: +1 opens, -1 closes.
OPEN, CLOSED = 1.0, -1.0


@dataclass(frozen=True)
class CollisionBox:
    """A box collision shape of `link`, centred at `center` in the link's frame, axes along the link's; it
    replaces the link's collision mesh(es) named `replaces` (file names, e.g. "moving_jaw.stl")."""

    link: str
    center: tuple[float, float, float]
    half_size: tuple[float, float, float]
    replaces: tuple[str, ...] = ()

    @classmethod
    def spanning(cls, link: str, low, high, replaces: tuple[str, ...] = ()) -> CollisionBox:
        """The box from corner `low` to corner `high` (link frame)."""
        lo, hi = np.asarray(low, dtype=float), np.asarray(high, dtype=float)
        (cx, cy, cz), (hx, hy, hz) = ((lo + hi) / 2).tolist(), ((hi - lo) / 2).tolist()
        return cls(link, (cx, cy, cz), (hx, hy, hz), replaces)


@dataclass(frozen=True)
class Decimation:
    """How a robot's visual meshes are lightened for CPU rendering: vertices welded on a `weld` grid (m; the default
    merges coincident ones only), then quadric simplification to `keep` of each part's triangles."""

    weld: float = 1e-6
    keep: float = 0.12


@dataclass(frozen=True)
class RobotSpec:
    """A robot variant: its model, the joints and links kitbench drives and reads, and its drive settings."""

    uid: str
    urdf: Callable[[], Path]  # the URDF SAPIEN loads (meshes beside it)
    mujoco_urdf: Callable[[], str]  # the same URDF as MuJoCo compiles it (absolute mesh paths, no visuals)
    arm_joints: tuple[str, ...]
    finger_joints: tuple[str, ...]
    finger_links: tuple[str, ...]
    # The TCP: a link, and the TCP's pose in it (p, wxyz). kitbench's TCP convention, which the experts' grasp
    # poses assume: z along the approach direction, y along the fingers' closing direction.
    tcp_link: str
    tcp_offset: tuple[tuple[float, float, float], tuple[float, float, float, float]]
    base_link: str  # the frame arm poses are expressed in (moves with a mobile base)
    ready_arm_qpos: tuple[float, ...]  # the arm at reset, before the task's noise
    finger_open: float  # finger joint target of an open gripper (action 1)
    finger_closed: float  # of a closed one (action -1), past the fingers' limit so a closed hand keeps squeezing
    base_pose: tuple[tuple[float, float, float], tuple[float, float, float, float]]  # where it stands (world)
    arm_velocity_limits: tuple[float, ...]  # rad/s: IK steps and the experts' timing stay within them
    arm_acceleration_limits: tuple[float, ...]  # rad/s^2
    # rad/s: the real arm's top joint speeds (its servos' or its maker's limits), which a person's joint targets are
    # rate-limited to as the real drives would follow them (`kitbench.teleop.limits`)
    joint_speed_limits: tuple[float, ...]
    # For each finger link, the direction in its own frame along which it closes (grasp detection).
    finger_closing_axes: tuple[tuple[float, float, float], ...] = ((0.0, -1.0, 0.0), (0.0, 1.0, 0.0))
    # One jaw fixed to the hand (the TCP on its face) and one moving onto it, instead of two fingers closing on the
    # TCP together: a held object's centre lies off the TCP by its half-width, along the TCP's y.
    fixed_jaw: bool = False
    ee_position_bound: float = 2.0  # m: `pd_ee_pose`'s position box around the base frame's origin (ManiSkill's)
    body_joints: tuple[str, ...] = ()  # position-driven joints outside the arm, delta-commanded
    body_ready: tuple[float, ...] = ()
    body_action_bound: float = 0.1  # rad or m a step
    base_joints: tuple[str, ...] = ()  # a mobile base's (x, y, yaw) root joints, velocity-driven
    base_max_speed: float = 1.0  # m/s, forward velocity action bound
    base_max_yaw_rate: float = 3.14  # rad/s
    cameras: tuple[CameraSpec, ...] = field(default_factory=tuple)
    # Whether image observations also hold the task's own cameras (False: a robot whose station brings its own).
    task_cameras: bool = True
    # How actions and observation.state express the joints (`kitbench.robots.units`): SI, or a real arm's layout.
    units: JointUnits = SI
    # IK's weight on the TCP's orientation against its position (1): an arm with fewer than six joints reaches
    # the position and as much of the orientation as it can with a low one.
    orientation_cost: float = 0.5
    # ManiSkill's Panda and Fetch gains: the same joint targets move an object as they do there (stiffer drives,
    # 1e4 and 5e2, turned a grasped peg ~10 degrees further: docs/fidelity.md).
    arm_stiffness: float = 1e3
    arm_damping: float = 1e2
    arm_force_limit: float = 100.0
    gripper_stiffness: float = 1e3
    gripper_damping: float = 1e2
    gripper_force_limit: float = 100.0
    body_stiffness: float = 1e3  # ManiSkill's Fetch body drives
    body_damping: float = 1e2
    body_force_limit: float = 100.0
    # The base joints follow a target that the velocity action integrates: stiff, so that a zero action holds the
    # base where it is against the arm's reaction forces, and damped to the velocity target.
    base_stiffness: float = 1e6
    base_damping: float = 1e4
    base_force_limit: float = 1e5
    finger_friction: float = 2.0
    # Link pairs that must not collide (SAPIEN's URDF loader ignores the SRDF's "Adjacent" entries).
    self_collision_ignored: tuple[tuple[str, str], ...] = ()
    # Links that never touch the ground or the table (a mobile base's wheels and body sit on the ground plane:
    # resting contacts there would push a base that holds still).
    ground_free_links: tuple[str, ...] = ()
    # Collision boxes replacing some of a link's collision meshes (`CollisionBox`): SAPIEN wraps each mesh in one
    # convex hull, which for a jaw moulded in one piece with its mount fills the gap an object is held in.
    collision_boxes: tuple[CollisionBox, ...] = ()
    # How its visual meshes are lightened for CPU rendering (kitbench.robots.visuals); None: kept as they are.
    decimate_visuals: Decimation | None = None
    # The room the robot needs in front of its base (m): the table's near edge stays at least this far from
    # the base's origin along +x. None: the standard table (its near edge under the Panda's base).
    table_clearance: float | None = None

    @property
    def has_base(self) -> bool:
        return bool(self.base_joints)

    def gripper_target(self, action: float) -> float:
        """Gripper command in [-1, 1] (-1 closed, 1 open: ManiSkill's) to the finger joint target, linear between
        `finger_closed` and `finger_open` as ManiSkill's gripper controller maps it."""
        a = min(1.0, max(-1.0, float(action)))
        return self.finger_closed + (a + 1.0) * 0.5 * (self.finger_open - self.finger_closed)

    @property
    def extra_action_names(self) -> list[str]:
        """Names of the action entries after the gripper: body joint deltas, then the base's two velocities."""
        names = [f"delta_{j}" for j in self.body_joints]
        if self.has_base:
            names += ["base_forward_velocity", "base_yaw_rate"]
        return names

    def extra_action_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The action box of the entries after the gripper: ManiSkill's [-1, 1] for each (`extra_action_scale`)."""
        h = np.ones(len(self.extra_action_names), dtype=np.float32)
        return -h, h

    def extra_action_scale(self) -> np.ndarray:
        """Action units per simulation unit (rad or m a step, m/s, rad/s) of each entry after the gripper: ManiSkill
        normalises its Fetch's body deltas and base velocities to [-1, 1]."""
        scale = [1.0 / self.body_action_bound] * len(self.body_joints)
        if self.has_base:
            scale += [1.0 / self.base_max_speed, 1.0 / self.base_max_yaw_rate]
        return np.asarray(scale, dtype=np.float64)

    @property
    def state_names(self) -> tuple[str, ...]:
        """LeRobot's `observation.state`: the arm's joints, the gripper, body joints, base x, y, yaw (`units`)."""
        return self.units.state_names(self)
