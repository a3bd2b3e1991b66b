"""The Franka Panda (arm + parallel gripper) from example-robot-data, loaded into SAPIEN.

The robot's links ignore gravity (a stand-in for the real arm's gravity compensation), joints are PD-driven and
the two fingers receive one shared target so they move together.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import sapien
from sapien import physx

from kitbench.robots.assets import panda_urdf_path
from kitbench.robots.visuals import lightweight_mesh
from kitbench.sim.cameras import CameraSpec

ARM_JOINTS = tuple(f"panda_joint{i}" for i in range(1, 8))
FINGER_JOINTS = ("panda_finger_joint1", "panda_finger_joint2")
TCP_LINK = "panda_hand_tcp"
HAND_LINK = "panda_hand"
FINGER_LINKS = ("panda_leftfinger", "panda_rightfinger")

READY_ARM_QPOS = np.array([0.0, np.pi / 8, 0.0, -5 * np.pi / 8, 0.0, 3 * np.pi / 4, np.pi / 4])
FINGER_OPEN = 0.04
FINGER_CLOSED = -0.01  # below the joint limit, so a closed hand keeps squeezing a thin object
# Width of a finger pad across the closing direction (the fingertip collision boxes are 1.8 cm wide); pass it
# as `pad_width` to the grasp helpers in kitbench.kits.shapes.
FINGER_PAD_WIDTH = 0.018
# The kit shapes are designed so that each has a closing direction through its centroid needing at most this
# opening, a bit over half of what the open hand spans (2 * FINGER_OPEN); tests/test_kit_physics.py checks it.
MAX_GRASP_WIDTH = 0.045


@dataclass(frozen=True)
class RobotSpec:
    """What distinguishes robot variants: their uid and the cameras they carry."""

    uid: str
    cameras: tuple[CameraSpec, ...] = field(default_factory=tuple)
    # Critically damped on the heaviest joint: 0.1 rad steps settle in ~0.1 s with < 1% overshoot, where
    # the reference gains (1e3, 1e2) reach only a quarter of a step within one 50 ms control period.
    arm_stiffness: float = 1e4
    arm_damping: float = 5e2
    arm_force_limit: float = 100.0
    gripper_stiffness: float = 1e3
    gripper_damping: float = 1e2
    gripper_force_limit: float = 100.0
    finger_friction: float = 2.0


HAND_CAMERA = CameraSpec(
    name="hand_camera",
    width=128,
    height=128,
    fov=np.pi / 2,
    position=(0.0464982, -0.0200011, 0.0360011),
    quaternion=(0.0, 0.70710678, 0.0, 0.70710678),  # looks along the gripper's approach axis
    mount=HAND_LINK,
)

ROBOTS: dict[str, RobotSpec] = {
    "panda": RobotSpec("panda"),
    "panda_wristcam": RobotSpec("panda_wristcam", cameras=(HAND_CAMERA,)),
}


def gripper_action_to_target(action: float) -> float:
    """Gripper command in [-1, 1] (-1 open, 1 closed) to the finger joint target."""
    a = min(1.0, max(-1.0, float(action)))
    return FINGER_OPEN + (a + 1.0) * 0.5 * (FINGER_CLOSED - FINGER_OPEN)


# Link pairs that must not collide. The example-robot-data SRDF lists these with reason "Adjacent" (or "Never"),
# which SAPIEN's loader ignores (it honours only "Default"): left in, the hand sits 2.3 cm deep in link7 and the
# solver fights that contact on every substep.
SELF_COLLISION_IGNORED = (
    ("panda_hand", "panda_link5"),
    ("panda_hand", "panda_link6"),
    ("panda_hand", "panda_link7"),
    ("panda_link5", "panda_link7"),
    ("panda_leftfinger", "panda_rightfinger"),
    ("panda_leftfinger", "panda_link7"),
    ("panda_rightfinger", "panda_link7"),
)

_PARSED: dict = {}


def _ignore_self_collisions(builder) -> None:
    """Give each ignored pair a shared bit in collision group 2 (SAPIEN skips pairs sharing such a bit)."""
    by_name = {b.name: b for b in builder.link_builders}
    for bit, (a, b) in enumerate(SELF_COLLISION_IGNORED):
        for name in (a, b):
            by_name[name].collision_groups[2] |= 1 << bit


def _parsed_panda(scene: sapien.Scene, finger_friction: float, render: bool):
    """The URDF parsed once per process (parsing costs ~20 ms; building from the parse, a few ms)."""
    key = (finger_friction, render)
    if key not in _PARSED:
        loader = scene.create_urdf_loader()
        loader.fix_root_link = True
        builder = loader.load_file_as_articulation_builder(str(panda_urdf_path()), srdf_file="")
        _ignore_self_collisions(builder)
        finger_material = physx.PhysxMaterial(finger_friction, finger_friction, 0.0)
        for link_builder in builder.link_builders:
            if not render:
                link_builder.visual_records = []
            for record in link_builder.visual_records:
                if record.type == "file":
                    record.filename = lightweight_mesh(record.filename)
            if link_builder.name in FINGER_LINKS:
                for record in link_builder.collision_records:
                    record.material = finger_material
                    record.patch_radius = 0.1
                    record.min_patch_radius = 0.1
        _PARSED[key] = builder
    return _PARSED[key]


class Panda:
    """A Panda in a scene: joint state, PD targets, the TCP frame and grasp detection."""

    def __init__(self, scene: sapien.Scene, spec: RobotSpec, base_pose: sapien.Pose, render: bool):
        self.spec = spec
        self.scene = scene
        builder = _parsed_panda(scene, spec.finger_friction, render).set_scene(scene)
        self.articulation: physx.PhysxArticulation = builder.build(fix_root_link=True)
        self.articulation.name = spec.uid
        self.articulation.set_root_pose(base_pose)
        self.base_pose = base_pose
        links = {link.name: link for link in self.articulation.links}
        for link in links.values():
            link.disable_gravity = True
        self.tcp = links[TCP_LINK]
        self.hand = links[HAND_LINK]
        self.fingers = tuple(links[name] for name in FINGER_LINKS)
        self.links = links
        joints = {j.name: j for j in self.articulation.active_joints}
        self.arm_joints = [joints[n] for n in ARM_JOINTS]
        self.finger_joints = [joints[n] for n in FINGER_JOINTS]
        for j in self.arm_joints:
            j.set_drive_properties(spec.arm_stiffness, spec.arm_damping, spec.arm_force_limit, "force")
        for j in self.finger_joints:
            j.set_drive_properties(spec.gripper_stiffness, spec.gripper_damping, spec.gripper_force_limit, "force")
        limits = np.array([j.limit[0] for j in self.arm_joints])
        self.arm_limits = limits  # (7, 2)
        self.dof = self.articulation.dof

    # -- state ---------------------------------------------------------------------------------
    def qpos(self) -> np.ndarray:
        return self.articulation.get_qpos()

    def qvel(self) -> np.ndarray:
        return self.articulation.get_qvel()

    def tcp_pose(self) -> sapien.Pose:
        return self.tcp.entity_pose

    def reset(self, arm_qpos: np.ndarray, finger: float = FINGER_OPEN) -> None:
        """Teleport to a configuration, at rest, with drive targets equal to it."""
        qpos = np.concatenate([arm_qpos, [finger, finger]]).astype(np.float32)
        self.articulation.set_qpos(qpos)
        self.articulation.set_qvel(np.zeros(self.dof, dtype=np.float32))
        self.articulation.set_qf(np.zeros(self.dof, dtype=np.float32))
        self.articulation.set_qacc(np.zeros(self.dof, dtype=np.float32))
        self.articulation.set_root_pose(self.base_pose)
        self.set_targets(arm_qpos, finger)

    def set_targets(self, arm_targets, finger_target: float) -> None:
        for joint, target in zip(self.arm_joints, arm_targets, strict=True):
            joint.set_drive_target(float(target))
        for joint in self.finger_joints:
            joint.set_drive_target(float(finger_target))

    def arm_targets(self) -> np.ndarray:
        return np.array([float(j.drive_target[0]) for j in self.arm_joints])

    # -- contact -------------------------------------------------------------------------------
    def is_grasping(self, body: sapien.Entity, min_impulse: float = 1e-4, max_angle_deg: float = 85.0) -> bool:
        """Both fingers press the body from opposite sides (contact impulse along each finger's closing axis)."""
        target = body.find_component_by_type(physx.PhysxRigidBaseComponent)
        impulses = [np.zeros(3), np.zeros(3)]
        for contact in self.scene.get_contacts():
            b0, b1 = contact.bodies
            for i, finger in enumerate(self.fingers):
                if b0 is finger and b1 is target:
                    sign = 1.0
                elif b1 is finger and b0 is target:
                    sign = -1.0
                else:
                    continue
                for point in contact.points:
                    impulses[i] += sign * point.impulse
        cos_max = np.cos(np.deg2rad(max_angle_deg))
        for i, finger in enumerate(self.fingers):
            impulse = impulses[i]
            norm = np.linalg.norm(impulse)
            if norm < min_impulse:
                return False
            # Closing direction: left finger closes along -y of its frame, right finger along +y.
            rot = finger.entity_pose.to_transformation_matrix()[:3, :3]
            closing = -rot[:, 1] if i == 0 else rot[:, 1]
            # The impulse on the finger from the object opposes the closing direction.
            if float(np.dot(-impulse, closing)) / norm < cos_max:
                return False
        return True
