"""LiftPegUpright-v1: stand a peg that lies on the table upright.

Success is geometric: the peg's long axis within 0.08 rad of vertical (either end up, any yaw) and its centre
within 5 mm of 0.12 m (its half-length) above the table. The reference framework's check (the third angle of an
XYZ Euler decomposition) accepts a horizontal peg held at 12 cm and rejects a truly upright one; this one does not.
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np
import sapien
from sapien import physx

from kitbench.envs.grasp import GraspHistory
from kitbench.envs.observations import pose7
from kitbench.envs.tabletop import TabletopEnv
from kitbench.errors import check_vector
from kitbench.geometry import quat_to_matrix, tilt_from_vertical
from kitbench.registration import register_env
from kitbench.sim.cameras import OBSERVATION_SIZE, CameraSpec, view
from kitbench.sim.scene import set_actor_pose

PEG_HALF_WIDTH = 0.025
PEG_HALF_LENGTH = 0.12
PEG_DENSITY = 1000.0
# ManiSkill's default material: its solution lets the peg pivot in the grasp as it stands it on the table, which a
# grippier peg (1.0) resists, ending 6-7 degrees off vertical (docs/fidelity.md).
PEG_FRICTION = 0.3
RED = (176 / 255, 14 / 255, 14 / 255, 1.0)
BLUE = (12 / 255, 42 / 255, 160 / 255, 1.0)
MAX_TILT = 0.08  # rad
MAX_Z_ERROR = 0.005  # m
LYING_QUAT = (math.cos(math.pi / 4), math.sin(math.pi / 4), 0.0, 0.0)  # long axis along world x
SPAWN_HALF_WIDTH = 0.1  # m: the peg's centre is drawn uniformly from a square this wide each side of the origin
# Robots for which the task is built smaller (peg and spawn square alike), with the same success criteria: the
# SO-101's jaw opens ~5 cm at its pads and it reaches ~26 cm from its base at table height, so its peg is half the
# size (12 x 2.5 x 2.5 cm, 75 g: the 5 cm peg would fill the jaw, and 0.6 kg is a third of a servo's stall torque at
# arm's length) and lies within 5 cm of the origin, 14-24 cm in front of the arm's base (tests/test_so101.py).
ROBOT_SCALE = {"so101": 0.5}


def peg_success(position, quaternion, half_length: float = PEG_HALF_LENGTH) -> tuple[bool, float, float]:
    """(success, tilt from vertical in rad, centre height error in m) for a pose of a peg `2 * half_length` long."""
    axis = quat_to_matrix(quaternion)[:, 0]
    tilt = tilt_from_vertical(axis)
    z_error = abs(float(position[2]) - half_length)
    return (tilt < MAX_TILT and z_error < MAX_Z_ERROR), tilt, z_error


def build_peg(scene: sapien.Scene, render: bool, scale: float = 1.0) -> sapien.Entity:
    """A square-section peg along its x axis, its +x half red and its -x half blue, `scale` times the standard
    size."""
    builder = scene.create_actor_builder()
    length, width = PEG_HALF_LENGTH * scale, PEG_HALF_WIDTH * scale
    material = physx.PhysxMaterial(PEG_FRICTION, PEG_FRICTION, 0.0)
    builder.add_box_collision(half_size=[length, width, width], material=material, density=PEG_DENSITY)
    if render:
        quarter = [length / 2, width, width]
        for sign, colour in ((1, RED), (-1, BLUE)):
            material = sapien.render.RenderMaterial(base_color=colour, roughness=0.5, specular=0.3)
            builder.add_box_visual(sapien.Pose([sign * length / 2, 0, 0]), quarter, material=material)
    return builder.build(name="peg")


@register_env("LiftPegUpright-v1", max_episode_steps=50)
class LiftPegUprightEnv(TabletopEnv):
    """Move a peg lying on the table to an upright position on the table (50 control steps)."""

    supported_robots = ("panda", "fetch", "so101")
    max_dense_reward = 3.0
    default_qpos_noise = 0.02
    environment_state_keys = ("peg_pose",)
    # Fetch's expert needs 121 steps (median; max 136) in pd_joint_pos and 148 (max 161) in pd_joint_delta_pos over
    # seeds 0-99 under ManiSkill's drives, within the real arm's joint limits (its wrist turns ~2 rad twice:
    # kitbench/planning/lift_peg_upright_fetch.py). 170 steps (8.5 s) leave room for the recipes' 10 settling steps
    # in pd_joint_pos; the Panda keeps the reference's 50.
    # The SO-101's expert (servos at half their no-load speed) needs median 37 steps (max 42) in pd_joint_pos over
    # seeds 10000-10299 and median 87 (max 99) in pd_joint_delta_pos over seeds 0-99, whose +-0.1 rad steps it takes
    # at 40% (`MEASURED_DELTA_TRACKING`, set for ManiSkill's Panda drives); 100 steps (5 s) hold both, and the
    # recipes' settling steps in pd_joint_pos.
    robot_max_episode_steps: ClassVar[dict[str, int]] = {"fetch": 170, "so101": 100}
    supports_object_scale = True  # the peg is built to `object_scale`; success asks for its own half-length
    success_criteria = ("upright", "at_height")
    failure_categories = ("never_grasped", "dropped", "released", "not_upright", "wrong_height")
    sensor_cameras = (
        CameraSpec.looking_at("base_camera", [0.3, 0, 0.6], [-0.1, 0, 0.1], *OBSERVATION_SIZE, math.pi / 2),
    )
    # "peg": the base camera lower, nearer and narrower (55 degrees, not 90), framing the spawn square and the swing
    # upright: the peg on 4.3-4.8x the pixels of the task's own framing, never cut by the picture's edge along the
    # expert's episodes (bench/camera_view.py); the CPU image config's recording (docs/observations.md). With the
    # SO-101 it moves the arm's front camera nearer and lower (52 degrees, not 57): the peg on 1.5-1.7x the pixels.
    camera_views: ClassVar[dict] = {
        "peg": {
            "base_camera": view([0.40, 0.0, 0.45], [-0.02, 0.0, 0.05], math.radians(55)),
            "front": view([0.24, 0.0, 0.26], [-0.04, 0.0, 0.025], math.radians(52)),
        }
    }
    expert: ClassVar[dict[str, str | type]] = {
        "panda": "kitbench.planning.lift_peg_upright_panda:LiftPegUprightPlanner",
        "fetch": "kitbench.planning.lift_peg_upright_fetch:FetchLiftPegUprightPlanner",
        "so101": "kitbench.planning.lift_peg_upright_so101:SO101LiftPegUprightPlanner",
    }

    @classmethod
    def variant_description(cls, robot_uid: str) -> str | None:
        scale = ROBOT_SCALE.get(robot_uid)
        if scale is None:
            return None
        length, width = 2 * PEG_HALF_LENGTH * scale * 100, 2 * PEG_HALF_WIDTH * scale * 100
        return (
            f"the peg at {scale:g} of the reference size ({length:g} x {width:g} x {width:g} cm), lying within "
            f"{SPAWN_HALF_WIDTH * scale * 100:g} cm of the origin; the same success test"
        )

    @property
    def task_scale(self) -> float:
        """The size of this robot's variant of the task (`ROBOT_SCALE`), before any `object_scale` perturbation."""
        return ROBOT_SCALE.get(self.robot_uid, 1.0)

    def _load_task(self, scene, render):
        self.peg_scale = self.object_scale * self.task_scale
        self.peg = build_peg(scene, render, self.peg_scale)

    @property
    def target_object(self):
        return self.peg

    def segmentation_names(self) -> tuple[str, ...]:
        return ("peg",)

    def failure_category(self, info: dict, grasp: GraspHistory) -> str | None:
        """Stages: grasp, keep holding (`dropped`: it slipped out of the closed hand; `released`: the hand let go
        before the peg stood), turn upright, set at the right height."""
        if info["success"]:
            return None
        if not grasp.ever_grasped:
            return "never_grasped"
        if not grasp.held_at_end:
            return "released" if grasp.released else "dropped"
        return "not_upright" if not info["upright"] else "wrong_height"

    def task_description(self) -> str:
        return "Pick up the peg lying on the table and stand it upright on the table."

    def _initialize_episode(self, rng, options):
        half = SPAWN_HALF_WIDTH * self.task_scale
        xy = rng.uniform(-half, half, 2)
        set_actor_pose(self.peg, [xy[0], xy[1], PEG_HALF_WIDTH * self.peg_scale], LYING_QUAT)
        if "peg_pose" in options:  # a given start, [x, y, z, qw, qx, qy, qz]: another simulator's, say
            pose = check_vector("options['peg_pose']", options["peg_pose"], 7)
            set_actor_pose(self.peg, pose[:3], pose[3:])

    def evaluate(self):
        pose = self.peg.pose
        success, tilt, z_error = peg_success(pose.p, pose.q, PEG_HALF_LENGTH * self.peg_scale)
        return {
            "success": success,
            "upright": tilt < MAX_TILT,
            "at_height": z_error < MAX_Z_ERROR,
            "tilt": tilt,
            "z_error": z_error,
        }

    def task_state(self):
        return {"peg_pose": pose7(self.peg.pose)}

    def compute_dense_reward(self, info):
        if info["success"]:
            return self.max_dense_reward
        pose = self.peg.pose
        upright = math.cos(info["tilt"])  # |peg axis . z|
        height = 1.0 - math.tanh(5.0 * info["z_error"])
        if self.robot.is_grasping(self.peg):
            reach = 1.0
        else:
            reach = 1.0 - math.tanh(5.0 * float(np.linalg.norm(pose.p - self.robot.tcp_pose().p)))
        return upright + height + reach / 5.0
