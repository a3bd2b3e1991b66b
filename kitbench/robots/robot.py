"""`Robot`: a robot described by a `RobotSpec`, built into a SAPIEN scene: joint state, PD targets, the TCP, a
mobile base's velocity drive, and grasp detection.

The robot's links ignore gravity (a stand-in for a real arm's gravity compensation), joints are PD-driven and
the fingers receive one shared target so they move together. A mobile base is a chain of two prismatic joints
and a yaw joint at the root (as the reference model's URDF has it), driven in velocity: a zero action holds it.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import sapien
from sapien import physx

from kitbench.robots.spec import RobotSpec

_PARSED: dict = {}
# Collision group bit shared by the links that must not touch the ground or the table (`ground_free_links`);
# the ground and the table carry it too (`kitbench.sim.scene`), and SAPIEN skips pairs sharing a group-2 bit.
GROUND_FREE_BIT = 1 << 31


def _parsed(scene: sapien.Scene, spec: RobotSpec, render: bool):
    """The URDF parsed once per process and robot (parsing costs ~20 ms for the Panda; building from the parse,
    a few ms)."""
    key = (spec.uid, spec.finger_friction, render)
    if key not in _PARSED:
        from kitbench.robots.visuals import lightweight_mesh

        loader = scene.create_urdf_loader()
        loader.fix_root_link = True
        builder = loader.load_file_as_articulation_builder(str(spec.urdf()), srdf_file="")
        by_name = {b.name: b for b in builder.link_builders}
        # each ignored pair shares a bit in collision group 2 (SAPIEN skips pairs sharing such a bit)
        for bit, (a, b) in enumerate(spec.self_collision_ignored):
            for name in (a, b):
                by_name[name].collision_groups[2] |= 1 << bit
        for name in spec.ground_free_links:
            by_name[name].collision_groups[2] |= GROUND_FREE_BIT
        finger_material = physx.PhysxMaterial(spec.finger_friction, spec.finger_friction, 0.0)
        for box in spec.collision_boxes:
            link_builder = by_name[box.link]
            kept = [r for r in link_builder.collision_records if Path(r.filename or "").name not in box.replaces]
            link_builder.collision_records = kept
            link_builder.add_box_collision(sapien.Pose(box.center), box.half_size)
        for link_builder in builder.link_builders:
            if not render:
                link_builder.visual_records = []
            if spec.decimate_visuals is not None:
                for record in link_builder.visual_records:
                    if record.type == "file":
                        record.filename = lightweight_mesh(record.filename, spec.decimate_visuals)
            if link_builder.name in spec.finger_links:
                for record in link_builder.collision_records:
                    record.material = finger_material
                    record.patch_radius = 0.1
                    record.min_patch_radius = 0.1
        _PARSED[key] = builder
    return _PARSED[key]


class Robot:
    """A robot in a scene (see the module docstring)."""

    def __init__(self, scene: sapien.Scene, spec: RobotSpec, base_pose: sapien.Pose, render: bool):
        self.spec = spec
        self.scene = scene
        builder = _parsed(scene, spec, render).set_scene(scene)
        self.articulation: physx.PhysxArticulation = builder.build(fix_root_link=True)
        self.articulation.name = spec.uid
        self.articulation.set_root_pose(base_pose)
        self._root_pose = base_pose
        links = {link.name: link for link in self.articulation.links}
        for link in links.values():
            link.disable_gravity = True
        self.links = links
        self.tcp = links[spec.tcp_link]
        self._tcp_offset = sapien.Pose(*spec.tcp_offset)
        self._base_link = links[spec.base_link]
        self.fingers = tuple(links[name] for name in spec.finger_links)
        joints = {j.name: j for j in self.articulation.active_joints}
        index = {j.name: i for i, j in enumerate(self.articulation.active_joints)}
        self.arm_joints = [joints[n] for n in spec.arm_joints]
        self.finger_joints = [joints[n] for n in spec.finger_joints]
        self.body_joints = [joints[n] for n in spec.body_joints]
        self.base_joints = [joints[n] for n in spec.base_joints]
        self._arm_index = np.array([index[n] for n in spec.arm_joints])
        self._finger_index = np.array([index[n] for n in spec.finger_joints])
        self._body_index = np.array([index[n] for n in spec.body_joints], dtype=int)
        self._base_index = np.array([index[n] for n in spec.base_joints], dtype=int)
        for j in self.arm_joints:
            j.set_drive_properties(spec.arm_stiffness, spec.arm_damping, spec.arm_force_limit, "force")
        for j in self.finger_joints:
            j.set_drive_properties(spec.gripper_stiffness, spec.gripper_damping, spec.gripper_force_limit, "force")
        for j in self.body_joints:
            j.set_drive_properties(spec.body_stiffness, spec.body_damping, spec.body_force_limit, "force")
        for j in self.base_joints:
            j.set_drive_properties(spec.base_stiffness, spec.base_damping, spec.base_force_limit, "force")
        self._base_target: np.ndarray = np.zeros(len(self.base_joints))
        self.arm_limits = np.array([j.limit[0] for j in self.arm_joints])  # (n, 2)
        self.body_limits = np.array([j.limit[0] for j in self.body_joints]).reshape(-1, 2)
        self.dof = self.articulation.dof

    # -- state ---------------------------------------------------------------------------------------------
    def qpos(self) -> np.ndarray:
        """Every active joint's position, in SAPIEN's joint order (`articulation.active_joints`)."""
        return self.articulation.get_qpos()

    def qvel(self) -> np.ndarray:
        return self.articulation.get_qvel()

    def arm_qpos(self) -> np.ndarray:
        return self.qpos()[self._arm_index]

    def gripper_opening(self) -> float:
        """The sum of the finger joints' positions (m): the gap between the fingers, for parallel grippers."""
        return float(self.qpos()[self._finger_index].sum())

    def body_qpos(self) -> np.ndarray:
        return self.qpos()[self._body_index]

    def base_state(self) -> np.ndarray:
        """A mobile base's (x, y, yaw) relative to where it stood at reset (empty without a base)."""
        return self.qpos()[self._base_index]

    def state_vector(self, qpos: np.ndarray) -> np.ndarray:
        """`spec.state_names` read off a full joint vector (`qpos()` or a measured one): arm joints, gripper
        opening, body joints, base x, y, yaw."""
        q = np.asarray(qpos)
        parts = [q[self._arm_index], [q[self._finger_index].sum()], q[self._body_index], q[self._base_index]]
        return np.concatenate([np.asarray(p, dtype=np.float64).reshape(-1) for p in parts])

    def tcp_pose(self) -> sapien.Pose:
        return self.tcp.entity_pose * self._tcp_offset

    @property
    def base_pose(self) -> sapien.Pose:
        """The world pose of the frame arm poses are expressed in (`spec.base_link`)."""
        if not self.spec.has_base:
            return self._root_pose  # fixed: the pose it was built at
        return self._base_link.entity_pose

    # -- commands ------------------------------------------------------------------------------------------
    def reset(self, arm_qpos: np.ndarray, finger: float | None = None) -> None:
        """Teleport to a configuration, at rest, with drive targets equal to it (body joints at their ready
        positions, a mobile base at its origin)."""
        finger = self.spec.finger_open if finger is None else finger
        qpos = np.zeros(self.dof, dtype=np.float32)
        qpos[self._arm_index] = arm_qpos
        qpos[self._finger_index] = finger
        qpos[self._body_index] = self.spec.body_ready
        self.articulation.set_qpos(qpos)
        self.articulation.set_qvel(np.zeros(self.dof, dtype=np.float32))
        self.articulation.set_qf(np.zeros(self.dof, dtype=np.float32))
        self.articulation.set_qacc(np.zeros(self.dof, dtype=np.float32))
        self.articulation.set_root_pose(self._root_pose)
        self.set_targets(arm_qpos, finger)
        self.set_body_targets(np.asarray(self.spec.body_ready, dtype=np.float64))
        self._base_target = np.zeros(len(self.base_joints))
        self.set_base_velocity(0.0, 0.0, 0.0)

    def set_targets(self, arm_targets, finger_target: float) -> None:
        for joint, target in zip(self.arm_joints, arm_targets, strict=True):
            joint.set_drive_target(float(target))
        for joint in self.finger_joints:
            joint.set_drive_target(float(finger_target))

    def set_body_targets(self, targets) -> None:
        for joint, target in zip(self.body_joints, targets, strict=True):
            joint.set_drive_target(float(target))

    def body_targets(self) -> np.ndarray:
        return np.array([float(j.drive_target[0]) for j in self.body_joints])

    def set_base_velocity(self, forward: float, yaw_rate: float, dt: float) -> None:
        """Drive a mobile base forward (along its heading) and turn it for `dt` seconds (nothing without a base):
        its joints track a target moving at that velocity, so a zero velocity holds the base still."""
        if not self.base_joints:
            return
        yaw = float(self._base_target[2])
        velocity = np.array([forward * math.cos(yaw), forward * math.sin(yaw), yaw_rate], dtype=np.float64)
        self._base_target = self._base_target + velocity * dt
        for joint, target, v in zip(self.base_joints, self._base_target, velocity, strict=True):
            joint.set_drive_target(float(target))
            joint.set_drive_velocity_target(float(v))

    def arm_targets(self) -> np.ndarray:
        return np.array([float(j.drive_target[0]) for j in self.arm_joints])

    # -- contact -------------------------------------------------------------------------------------------
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
            rot = finger.entity_pose.to_transformation_matrix()[:3, :3]
            closing = rot @ np.asarray(self.spec.finger_closing_axes[i])
            # The impulse on the finger from the object opposes the closing direction.
            if float(np.dot(-impulse, closing)) / norm < cos_max:
                return False
        return True
