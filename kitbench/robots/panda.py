"""The Franka Panda (arm + parallel gripper) from example-robot-data: its specs, `panda` and `panda_wristcam`
(with a hand camera). The model ships with the `example-robot-data` package (`kitbench.robots.assets`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from kitbench.robots.assets import panda_mujoco_urdf, panda_urdf_path
from kitbench.robots.registry import register_robot
from kitbench.robots.spec import Decimation, RobotSpec
from kitbench.sim.cameras import OBSERVATION_SIZE, CameraSpec

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


HAND_CAMERA = CameraSpec(
    name="hand_camera",
    width=OBSERVATION_SIZE[0],
    height=OBSERVATION_SIZE[1],
    fov=np.pi / 2,
    position=(0.0464982, -0.0200011, 0.0360011),
    quaternion=(0.0, 0.70710678, 0.0, 0.70710678),  # looks along the gripper's approach axis
    mount=HAND_LINK,
)

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
ARM_VELOCITY_LIMITS = (2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61)  # rad/s, the real Panda's joint limits
ARM_ACCELERATION_LIMITS = (15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0)  # rad/s^2, Franka's datasheet
# Task frame: table top at z = 0, the Panda's base at its near edge facing +x.
BASE_POSE = ((-0.615, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0))

PANDA = RobotSpec(
    uid="panda",
    urdf=panda_urdf_path,
    mujoco_urdf=panda_mujoco_urdf,
    arm_joints=ARM_JOINTS,
    finger_joints=FINGER_JOINTS,
    finger_links=FINGER_LINKS,
    tcp_link=TCP_LINK,
    tcp_offset=((0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0)),
    base_link="panda_link0",
    ready_arm_qpos=tuple(float(v) for v in READY_ARM_QPOS),
    finger_open=FINGER_OPEN,
    finger_closed=FINGER_CLOSED,
    base_pose=BASE_POSE,
    arm_velocity_limits=ARM_VELOCITY_LIMITS,
    arm_acceleration_limits=ARM_ACCELERATION_LIMITS,
    joint_speed_limits=ARM_VELOCITY_LIMITS,
    self_collision_ignored=SELF_COLLISION_IGNORED,
    decimate_visuals=Decimation(),
)
PANDA_WRISTCAM = replace(PANDA, uid="panda_wristcam", cameras=(HAND_CAMERA,))
register_robot(PANDA, PANDA_WRISTCAM)
