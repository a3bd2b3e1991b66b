"""The SO-101 (LeRobot's own arm: five STS3215 servos for the body, a sixth driving one moving jaw) from
example-robot-data's `so_arm_description` (TheRobotStudio's `so101_new_calib` URDF, whose zero configuration is
the middle of each joint's range, as LeRobot's calibration defines it): its spec, `so101`.

Its actions and `observation.state` are in the real arm's layout (`kitbench.robots.units.SO_FOLLOWER`): the five
body joints in degrees and the jaw from 0 (closed) to 100 (open), named `<motor>.pos` as LeRobot's SO follower
reports them. The joints' radians stay inside the simulation (controllers, planners, the state obs mode's `qpos`).

Five joints place the jaw at a position with two of its three orientation angles: the approach axis's pitch in
the arm's vertical plane (shoulder lift, elbow, wrist flex) and the roll about it (wrist roll); the approach's
heading is that of the arm's plane, set by the shoulder pan and the position. End-effector modes solve for the
position first and the orientation as far as that allows (`orientation_cost`).
"""

from __future__ import annotations

import math

from kitbench.robots.assets import so101_mujoco_urdf, so101_urdf_path
from kitbench.robots.registry import register_robot
from kitbench.robots.spec import CollisionBox, Decimation, RobotSpec
from kitbench.robots.units import SO_FOLLOWER
from kitbench.sim.cameras import OBSERVATION_SIZE, CameraSpec

# LeRobot's motor order (lerobot/robots/so_follower/so_follower.py), which the URDF's joint names follow.
ARM_JOINTS = ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll")
JAW_JOINT = "gripper"
FIXED_JAW_LINK = "gripper_link"  # the fixed jaw is moulded with the wrist roll's follower horn
MOVING_JAW_LINK = "moving_jaw_so101_v1_link"
# The jaw's joint range (rad, the URDF's): -10 degrees presses the jaws together, 100 degrees opens them ~7 cm at the
# tips. LeRobot's gripper 0..100 spans the range calibrated on the real arm; kitbench takes it to be this one.
JAW_RANGE = (-0.174533, 1.74533)

# STS3215 (7.4 V, 1:345 gear, the SO-101 follower's servo), Feetech's datasheet: stall torque 19.5 kg cm (1.9 N m),
# no-load speed 0.222 s per 60 degrees (4.7 rad/s). Acceleration: LeRobot writes the servo's Acceleration register
# to 254 (`FeetechMotorsBus.configure_motors`), in units of 100 steps/s^2 of 4096 a turn: 39 rad/s^2.
STALL_TORQUE = 1.9  # N m
NO_LOAD_SPEED = 4.7  # rad/s
SERVO_ACCELERATION = 39.0  # rad/s^2
# LeRobot's SO follower caps the jaw's servo at 50% of its torque (`Max_Torque_Limit` 500 of 1000).
JAW_TORQUE = 0.5 * STALL_TORQUE
# The servo's position loop as a PD drive: the links (0.08-0.10 kg each) ignore gravity as every kitbench arm's
# do, so the gains only set how fast a target is reached. 60 N m/rad saturates the torque 0.032 rad (1.8 degrees)
# from the target, as the real servo drives at full torque until close. With 1.0 N m s/rad, a 0.1 rad step of any
# of the first four joints is 95-102% done after one 50 ms control period and settled after two (30 N m/rad: 78-79%;
# damping 0.6: up to 13% overshoot); tests/test_so101.py checks the tracking.
ARM_STIFFNESS = 60.0
ARM_DAMPING = 1.0
# the jaw (12 g) swings from open to shut in two control periods (gripper.pos 100 -> 8.6 -> 0.7 with nothing held)
JAW_STIFFNESS = 10.0
JAW_DAMPING = 0.2

# The gripper frame the URDF ships (`gripper_frame_link`) sits on the fixed jaw's inner face near its tip; the TCP
# is on that face 16 mm further back (23 mm from the tip, the 60 mm pad's outer part, so that it holds low objects),
# turned so that z approaches and y points from the fixed jaw to the moving one (kitbench's TCP convention, the
# fingers closing along y). An object of half-width w is held with its centre w along y from the TCP.
TCP_LINK = "gripper_frame_link"
TCP_OFFSET = ((0.0, 0.0, -0.0164), (math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)))

# SAPIEN wraps a collision mesh in its convex hull: the fixed jaw's (one piece with the wrist roll's horn) and the
# moving jaw's would fill the gap between them. Boxes fitted to the meshes' vertices replace them (link frames,
# measured with the jaw at 0): each jaw's pad, and the root it hangs from.
_FOLLOWER = ("wrist_roll_follower_so101_v1.stl",)
_JAW = ("moving_jaw_so101_v1.stl",)
COLLISION_BOXES = (
    CollisionBox.spanning(FIXED_JAW_LINK, (-0.0337, -0.0116, -0.1044), (-0.0079, 0.0111, -0.045), _FOLLOWER),
    CollisionBox.spanning(FIXED_JAW_LINK, (-0.0352, -0.020, -0.045), (-0.002, 0.020, -0.005), _FOLLOWER),
    CollisionBox.spanning(MOVING_JAW_LINK, (-0.0123, -0.082, 0.008), (0.0065, -0.030, 0.030), _JAW),
    CollisionBox.spanning(MOVING_JAW_LINK, (-0.0123, -0.030, -0.004), (0.0086, -0.005, 0.042), _JAW),
)

# Where it stands: clamped to the table's near edge like a real SO-101, facing +x: a jaw pointing down reaches
# ~0.3 m out at table height (0.27 m out and 0.2 m to the side), which covers the tasks' workspaces near the origin.
BASE_POSE = ((-0.19, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0))
# The jaw 13 cm above the table, 20 cm in front of the base, pointing down: the arm's usual start over the work.
READY_ARM_QPOS = (0.0, -0.45, 0.45, 1.45, 1.5708)

# A typical SO-101 station's two cameras, named as LeRobot's docs name them in `lerobot-record --robot.cameras`:
# `front`, across the table looking back at the arm, and `wrist`, on the fixed jaw's mount looking along the jaw.
FRONT_CAMERA = CameraSpec.looking_at("front", [0.25, 0.0, 0.30], [-0.12, 0.0, 0.0], *OBSERVATION_SIZE, 1.0)
# under the fixed jaw (link -x) near the wrist, looking along the approach (link -z) tilted 15 degrees towards the
# jaws: the jaw's tip in the upper third of the image, the object between the jaws below it
WRIST_CAMERA = CameraSpec(
    "wrist",
    *OBSERVATION_SIZE,
    1.5,
    (-0.06, 0.0, -0.02),
    (math.cos(math.radians(37.5)), 0.0, math.sin(math.radians(37.5)), 0.0),
    mount=FIXED_JAW_LINK,
)

SO101 = RobotSpec(
    uid="so101",
    urdf=so101_urdf_path,
    mujoco_urdf=so101_mujoco_urdf,
    arm_joints=ARM_JOINTS,
    finger_joints=(JAW_JOINT,),
    finger_links=(FIXED_JAW_LINK, MOVING_JAW_LINK),
    tcp_link=TCP_LINK,
    tcp_offset=TCP_OFFSET,
    base_link="base_link",
    ready_arm_qpos=READY_ARM_QPOS,
    finger_open=JAW_RANGE[1],
    finger_closed=JAW_RANGE[0],
    base_pose=BASE_POSE,
    arm_velocity_limits=(NO_LOAD_SPEED,) * 5,
    arm_acceleration_limits=(SERVO_ACCELERATION,) * 5,
    joint_speed_limits=(NO_LOAD_SPEED,) * 5,
    # the fixed jaw closes along its link's +x (towards the moving jaw), the moving jaw along its link's -x
    finger_closing_axes=((1.0, 0.0, 0.0), (-1.0, 0.0, 0.0)),
    fixed_jaw=True,
    ee_position_bound=0.5,
    cameras=(FRONT_CAMERA, WRIST_CAMERA),
    task_cameras=False,
    arm_stiffness=ARM_STIFFNESS,
    arm_damping=ARM_DAMPING,
    arm_force_limit=STALL_TORQUE,
    gripper_stiffness=JAW_STIFFNESS,
    gripper_damping=JAW_DAMPING,
    gripper_force_limit=JAW_TORQUE,
    collision_boxes=COLLISION_BOXES,
    # its STL exports tessellate every fillet in slivers a fraction of a millimetre wide, which stall the decimation
    # at 20-50% of the triangles; welded on a 0.3 mm grid they merge (39% left), and 30% of that keeps every mesh's
    # extent to 0.9 mm (12%, 38k of 323k triangles; 12% of it lost 5.7 mm of the moving jaw): docs/robots.md
    decimate_visuals=Decimation(weld=3e-4, keep=0.3),
    self_collision_ignored=(
        ("base_link", "shoulder_link"),
        ("shoulder_link", "upper_arm_link"),
        ("upper_arm_link", "lower_arm_link"),
        ("lower_arm_link", "wrist_link"),
        ("wrist_link", "gripper_link"),
        ("gripper_link", MOVING_JAW_LINK),
    ),
    orientation_cost=0.05,
    units=SO_FOLLOWER,
)
register_robot(SO101)
