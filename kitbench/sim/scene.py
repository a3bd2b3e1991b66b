"""Builds the SAPIEN scene every tabletop task stands in.

A scene is created with a render system only when images are needed, so state-only use never touches Vulkan.
Task frame: table top at z = 0, robot base at (-0.615, 0, 0) facing +x.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import sapien
from sapien import physx

from kitbench.errors import KitbenchError

TABLE_HALF_SIZE = (0.9, 0.6, 0.46)  # a 1.8 x 1.2 m table, 0.92 m tall
TABLE_CENTER = (-0.12, 0.0)
GROUND_Z = -0.92


@dataclass(frozen=True)
class SimConfig:
    """Physics timing and solver settings (PhysX CPU)."""

    sim_freq: int = 100
    control_freq: int = 20
    solver_position_iterations: int = 15
    solver_velocity_iterations: int = 1
    contact_offset: float = 0.02
    rest_offset: float = 0.0
    bounce_threshold: float = 2.0
    # PhysX's persistent contact manifold: the Panda holds shapes reliably only with it (without it the
    # AssemblingKits expert dropped 118 of 500 shapes); its artefacts on small pieces are handled by the kit's
    # own contact offset (envs/assembling_kits.py, docs/kit-physics.md).
    enable_pcm: bool = True
    # The material of every shape that names none (ManiSkill's defaults: static and dynamic friction, restitution).
    default_material: tuple[float, float, float] = (0.3, 0.3, 0.0)
    # 0: no body ever sleeps. PhysX skips sleeping bodies, which makes a resting scene step ~8x faster but lets
    # results depend on when a body fell asleep and woke; every body is simulated every substep by default.
    sleep_threshold: float = 0.0

    def __post_init__(self):
        if self.sim_freq <= 0 or self.control_freq <= 0:
            raise KitbenchError(f"sim_freq and control_freq must be positive, got {self.sim_freq}, {self.control_freq}")
        if self.sim_freq % self.control_freq:
            raise KitbenchError(f"sim_freq ({self.sim_freq}) must be a multiple of control_freq ({self.control_freq})")

    @property
    def substeps(self) -> int:
        return self.sim_freq // self.control_freq


def create_scene(config: SimConfig, render: bool) -> sapien.Scene:
    """A fresh scene with PhysX CPU and, only if asked, a render system."""
    scene_config = physx.PhysxSceneConfig()
    scene_config.bounce_threshold = config.bounce_threshold
    scene_config.enable_pcm = config.enable_pcm
    scene_config.enable_tgs = True
    scene_config.enable_enhanced_determinism = True
    physx.set_scene_config(scene_config)
    physx.set_default_material(*config.default_material)
    physx.set_shape_config(contact_offset=config.contact_offset, rest_offset=config.rest_offset)
    physx.set_body_config(
        solver_position_iterations=config.solver_position_iterations,
        solver_velocity_iterations=config.solver_velocity_iterations,
        sleep_threshold=config.sleep_threshold,
    )
    systems = [physx.PhysxCpuSystem()]
    if render:
        systems.append(sapien.render.RenderSystem())
    scene = sapien.Scene(systems)
    scene.set_timestep(1.0 / config.sim_freq)
    return scene


def add_table_and_ground(
    scene: sapien.Scene, render: bool, near_edge: float | None = None, shared_bits: int = 0
) -> sapien.Entity:
    """A static table whose top is z = 0 and a floor below it.

    `near_edge`: the table starts at this x instead of its own near edge (-1.02), so a robot standing further
    back fits in front of it. `shared_bits`: collision group-2 bits the table and the floor share with robot
    links that must touch neither (SAPIEN skips a pair of shapes sharing such a bit)."""
    builder = scene.create_actor_builder()
    half = np.array(TABLE_HALF_SIZE)
    center_x = TABLE_CENTER[0]
    if near_edge is not None and near_edge > center_x - half[0]:
        far_edge = center_x + half[0]
        half[0] = (far_edge - near_edge) / 2
        center_x = (far_edge + near_edge) / 2
    pose = sapien.Pose([center_x, TABLE_CENTER[1], -half[2]])
    builder.add_box_collision(pose=pose, half_size=half)
    if render:
        material = sapien.render.RenderMaterial(base_color=[0.66, 0.55, 0.42, 1.0], roughness=0.7, specular=0.1)
        builder.add_box_visual(pose=pose, half_size=half, material=material)
    table = builder.build_static(name="table")
    ground = scene.create_actor_builder()
    _share_bits(table, shared_bits)
    ground.add_plane_collision(sapien.Pose([0, 0, GROUND_Z], [0.7071068, 0, -0.7071068, 0]))
    if render:
        ground.add_plane_visual(
            sapien.Pose([0, 0, GROUND_Z], [0.7071068, 0, -0.7071068, 0]),
            scale=[10, 10, 10],
            material=sapien.render.RenderMaterial(base_color=[0.85, 0.85, 0.85, 1.0], roughness=0.9),
        )
    _share_bits(ground.build_static(name="ground"), shared_bits)
    if render:
        scene.set_ambient_light([0.3, 0.3, 0.3])
        scene.add_directional_light([1, 1, -1], [1, 1, 1], shadow=False)
        scene.add_directional_light([0, 0, -1], [1, 1, 1])
    return table


def _share_bits(actor: sapien.Entity, bits: int) -> None:
    if not bits:
        return
    for shape in actor.find_component_by_type(physx.PhysxRigidBaseComponent).collision_shapes:
        groups = list(shape.collision_groups)
        groups[2] |= bits
        shape.set_collision_groups(groups)


def set_actor_pose(actor: sapien.Entity, p, q) -> None:
    """Teleport a rigid actor and zero its velocity (a teleported body must not keep the old momentum)."""
    actor.set_pose(sapien.Pose(np.asarray(p, dtype=np.float32), np.asarray(q, dtype=np.float32)))
    body = actor.find_component_by_type(physx.PhysxRigidDynamicComponent)
    if body is not None and not body.kinematic:
        body.set_linear_velocity(np.zeros(3))
        body.set_angular_velocity(np.zeros(3))
