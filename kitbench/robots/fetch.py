"""Fetch (mobile base, torso, 7-joint arm, parallel gripper, pan-tilt head) from the reference framework's model:
its spec, `fetch`.

The model's files come from the package index at set-up time (`kitbench.robots.fetch_assets`). Its base is the
reference URDF's chain of two prismatic joints and a yaw joint at the root, driven here to hold or follow the
base velocity action; the wheels are fixed links. Nothing of the robot touches the ground or the table below the
arm (`ground_free_links`): a resting contact there would push a base that holds still, and the reference
framework too keeps the base and wheels out of collision with the ground.

Action layout (`kitbench.robots.spec`): arm part (the control mode's), gripper, then head pan, head tilt and torso
deltas (+-0.1 rad or m a step), then the base's forward velocity (m/s) and yaw rate (rad/s). In `pd_joint_pos`:
13 entries, indices 0-6 arm, 7 gripper, 8-10 body, 11-12 base.
"""

from __future__ import annotations

import math
from pathlib import Path

from kitbench.robots.registry import register_robot
from kitbench.robots.spec import Decimation, RobotSpec
from kitbench.sim.cameras import OBSERVATION_SIZE, CameraSpec

ARM_JOINTS = (
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "upperarm_roll_joint",
    "elbow_flex_joint",
    "forearm_roll_joint",
    "wrist_flex_joint",
    "wrist_roll_joint",
)
BODY_JOINTS = ("head_pan_joint", "head_tilt_joint", "torso_lift_joint")
BASE_JOINTS = ("root_x_axis_joint", "root_y_axis_joint", "root_z_rotation_joint")
FINGER_JOINTS = ("l_gripper_finger_joint", "r_gripper_finger_joint")
FINGER_LINKS = ("l_gripper_finger_link", "r_gripper_finger_link")
# The reference's "rest" keyframe: torso fully up (0.386 m), head tilted down at the table, arm folded forward.
READY_ARM_QPOS = (-0.370, -1.032, 0.695, 0.955, -0.1, 2.077, 0.0)
BODY_READY = (0.0, 0.562, 0.386)
# The real arm's limits, as the robot's maker configures its motion planner (fetch_ros, fetch_moveit_config/config/
# joint_limits.yaml): velocities at or below the URDF's (the shoulder lift 1.0 rad/s against the URDF's 1.454),
# accelerations 1.0-2.5 rad/s^2. The experts' timing keeps within them, so demonstrations are motions the real
# Fetch can make.
ARM_VELOCITY_LIMITS = (1.256, 1.0, 1.57, 1.5, 1.57, 2.26, 2.26)
ARM_ACCELERATION_LIMITS = (1.5, 1.0, 1.5, 1.5, 1.5, 2.5, 2.5)
# The URDF's joint velocity limits (the hardware's; the planner's above stay below them): what a person's joint
# targets are rate-limited to.
URDF_VELOCITY_LIMITS = (1.256, 1.454, 1.571, 1.521, 1.571, 2.268, 2.268)
# The SRDF's pairs (SAPIEN's loader, given no SRDF, would keep them colliding).
SELF_COLLISION_IGNORED = (
    ("torso_fixed_link", "torso_lift_link"),
    ("bellows_link2", "torso_fixed_link"),
    ("bellows_link2", "base_link"),
    ("head_tilt_link", "torso_lift_link"),
    ("shoulder_lift_link", "torso_lift_link"),
    ("wrist_roll_link", "forearm_roll_link"),
    ("gripper_link", "wrist_flex_link"),
    ("l_gripper_finger_link", "r_gripper_finger_link"),
    ("upperarm_roll_link", "head_pan_link"),
    ("upperarm_roll_link", "head_tilt_link"),
)
GROUND_FREE_LINKS = (
    "base_link",
    "r_wheel_link",
    "l_wheel_link",
    "torso_fixed_link",
    "bellows_link",
    "bellows_link2",
    "estop_link",
    "laser_link",
)
# The reference's cameras: fetch_head on the head camera link, fetch_hand behind and above the gripper.
HEAD_CAMERA = CameraSpec("fetch_head", *OBSERVATION_SIZE, 2.0, (0.0, 0.0, 0.0), mount="head_camera_link")
HAND_CAMERA = CameraSpec("fetch_hand", *OBSERVATION_SIZE, 2.0, (-0.1, 0.0, 0.1), mount="gripper_link")
TABLE_HEIGHT = 0.92  # the table top is z = 0; the base stands on the floor below it


# Imported on first use: the asset module's downloader (urllib, html.parser) adds ~11 ms to `import kitbench`,
# which most runs, Panda-only, never need.
def _urdf() -> Path:
    from kitbench.robots.fetch_assets import fetch_urdf_path

    return fetch_urdf_path()


def _mujoco_urdf() -> str:
    from kitbench.robots.fetch_assets import fetch_mujoco_urdf

    return fetch_mujoco_urdf()


FETCH = RobotSpec(
    uid="fetch",
    urdf=_urdf,
    mujoco_urdf=_mujoco_urdf,
    arm_joints=ARM_JOINTS,
    finger_joints=FINGER_JOINTS,
    finger_links=FINGER_LINKS,
    # the gripper link's x axis is its approach direction and its fingers close along its y axis: the TCP turns
    # it by 90 degrees about y so that z approaches and y closes, as every TCP in kitbench does
    tcp_link="gripper_link",
    tcp_offset=((0.0, 0.0, 0.0), (math.cos(math.pi / 4), 0.0, math.sin(math.pi / 4), 0.0)),
    base_link="base_link",
    ready_arm_qpos=READY_ARM_QPOS,
    finger_open=0.05,
    finger_closed=-0.01,
    base_pose=((-1.05, 0.0, -TABLE_HEIGHT), (1.0, 0.0, 0.0, 0.0)),
    arm_velocity_limits=ARM_VELOCITY_LIMITS,
    arm_acceleration_limits=ARM_ACCELERATION_LIMITS,
    joint_speed_limits=URDF_VELOCITY_LIMITS,
    finger_closing_axes=((0.0, 1.0, 0.0), (0.0, -1.0, 0.0)),  # the left finger sits at -y and closes along +y
    ee_position_bound=1.5,  # the base frame is on the floor: the TCP works 0.9-1.4 m above it
    body_joints=BODY_JOINTS,
    body_ready=BODY_READY,
    base_joints=BASE_JOINTS,
    cameras=(HEAD_CAMERA, HAND_CAMERA),
    self_collision_ignored=SELF_COLLISION_IGNORED,
    ground_free_links=GROUND_FREE_LINKS,
    # the reference's visual meshes (DAE, 9 MB) cost rgb observations 4x: 8 steps/s with them, 28-33 decimated
    # (bench/run.py, 3 cameras at 128x128); the decimated copies keep each part's colour but not its texture
    decimate_visuals=Decimation(),
    table_clearance=0.35,  # the base's radius is 0.28 m; its bumper stays 7 cm from the table
)
register_robot(FETCH)
