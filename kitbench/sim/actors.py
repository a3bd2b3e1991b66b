"""Actors from in-memory geometry: convex collision pieces or a static triangle mesh, plus a triangle-mesh visual.

Procedural assets (kit boards, shapes) never touch the disk; visuals are attached only in scenes that render.
"""

from __future__ import annotations

import numpy as np
import sapien
from sapien import physx

# PhysX cooks convex hulls with a fixed plane tolerance of 0.7 mm (PxCookingParams::planeTolerance, not exposed by
# SAPIEN): cooked in metres, a kit shape's pieces come out up to 0.48 mm off their outline (a board's, 0.7 mm), most
# of a pocket's 0.69-1.57 mm clearance. Cooking the vertices in millimetres (x1000) and scaling the shape back by
# 1/1000 keeps the shapes' hulls exact (tests/test_kit_physics.py). (Scales of 10 and 100 cook as exactly; which
# scale is used moved, but did not remove, the contact failures that the board's triangle mesh fixed:
# kits/board.py.)
COOKING_SCALE = 1000.0


def convex_collision_shape(vertices: np.ndarray, material: physx.PhysxMaterial) -> physx.PhysxCollisionShapeConvexMesh:
    """A PhysX convex hull of `vertices` (metres) cooked at COOKING_SCALE so that it keeps the exact outline."""
    scaled = np.ascontiguousarray(np.asarray(vertices, dtype=np.float64) * COOKING_SCALE, dtype=np.float32)
    return physx.PhysxCollisionShapeConvexMesh(scaled, np.full(3, 1.0 / COOKING_SCALE, dtype=np.float32), material)


def cooked_vertices(shape: physx.PhysxCollisionShapeConvexMesh) -> np.ndarray:
    """The hull PhysX actually collides with, in the shape's frame (metres)."""
    return np.asarray(shape.get_vertices(), dtype=np.float64) * np.asarray(shape.get_scale(), dtype=np.float64)


def _flat_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Per-vertex normals for a mesh whose faces do not share vertices (flat shading)."""
    tri = vertices[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    normals = np.zeros_like(vertices)
    for k in range(3):
        normals[faces[:, k]] = n
    return normals.astype(np.float32)


def _visual_body(visual: tuple[np.ndarray, np.ndarray], color) -> sapien.render.RenderBodyComponent:
    vertices, faces = visual
    vertices = np.ascontiguousarray(vertices, dtype=np.float32)
    faces = np.ascontiguousarray(faces, dtype=np.uint32)
    mat = sapien.render.RenderMaterial(base_color=[*color[:3], 1.0], roughness=0.6, specular=0.2)
    shape = sapien.render.RenderShapeTriangleMesh(
        vertices, faces, _flat_normals(vertices, faces), np.zeros((len(vertices), 2), np.float32), mat
    )
    body = sapien.render.RenderBodyComponent()
    body.attach(shape)
    return body


def _add_entity(
    scene: sapien.Scene,
    name: str,
    component: physx.PhysxRigidBaseComponent,
    visual: tuple[np.ndarray, np.ndarray] | None,
    color,
    pose: sapien.Pose | None,
) -> sapien.Entity:
    entity = sapien.Entity()
    entity.name = name
    if visual is not None:
        entity.add_component(_visual_body(visual, color))
    entity.add_component(component)
    if pose is not None:
        entity.pose = pose
    scene.add_entity(entity)
    return entity


def build_convex_actor(
    scene: sapien.Scene,
    name: str,
    convex_pieces: list[np.ndarray],
    visual: tuple[np.ndarray, np.ndarray] | None,
    color,
    body_type: str,
    material: physx.PhysxMaterial,
    density: float = 1000.0,
    pose: sapien.Pose | None = None,
    contact_offset: float | None = None,
) -> sapien.Entity:
    """A static or dynamic actor whose collision is the union of convex pieces (an exact decomposition).

    `contact_offset` (metres) overrides the scene's default for these pieces only.
    """
    component: physx.PhysxRigidBaseComponent
    if body_type == "static":
        component = physx.PhysxRigidStaticComponent()
    elif body_type == "dynamic":
        component = physx.PhysxRigidDynamicComponent()
    else:
        raise ValueError(f"unknown body_type {body_type!r}; valid choices: static, dynamic")
    for piece in convex_pieces:
        shape = convex_collision_shape(piece, material)
        shape.set_density(density)
        if contact_offset is not None:
            shape.set_contact_offset(contact_offset)
        component.attach(shape)
    return _add_entity(scene, name, component, visual, color, pose)


def build_static_mesh_actor(
    scene: sapien.Scene,
    name: str,
    mesh: tuple[np.ndarray, np.ndarray],
    visual: tuple[np.ndarray, np.ndarray] | None,
    color,
    material: physx.PhysxMaterial,
    pose: sapien.Pose | None = None,
    contact_offset: float | None = None,
) -> sapien.Entity:
    """A static actor that collides as one triangle mesh (`mesh`: welded vertices (N,3) in metres, faces (M,3)
    wound outward). Triangle meshes are not cooked into hulls, so the vertices are used as they are (PhysX allows
    them on static bodies only). `contact_offset` (metres) overrides the scene's default for the mesh."""
    vertices, faces = mesh
    shape = physx.PhysxCollisionShapeTriangleMesh(
        np.ascontiguousarray(vertices, dtype=np.float32),
        np.ascontiguousarray(faces, dtype=np.uint32),
        np.ones(3, dtype=np.float32),
        material,
    )
    if contact_offset is not None:
        shape.set_contact_offset(contact_offset)
    component = physx.PhysxRigidStaticComponent()
    component.attach(shape)
    return _add_entity(scene, name, component, visual, color, pose)
