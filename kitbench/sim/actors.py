"""Actors from in-memory geometry: convex collision pieces plus a triangle-mesh visual.

Procedural assets (kit boards, shapes) never touch the disk; visuals are attached only in scenes that render.
"""

from __future__ import annotations

import numpy as np
import sapien
from sapien import physx


def _flat_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Per-vertex normals for a mesh whose faces do not share vertices (flat shading)."""
    tri = vertices[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    normals = np.zeros_like(vertices)
    for k in range(3):
        normals[faces[:, k]] = n
    return normals.astype(np.float32)


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
) -> sapien.Entity:
    """A static or dynamic actor whose collision is the union of convex pieces (an exact decomposition)."""
    entity = sapien.Entity()
    entity.name = name
    if visual is not None:
        vertices, faces = visual
        vertices = np.ascontiguousarray(vertices, dtype=np.float32)
        faces = np.ascontiguousarray(faces, dtype=np.uint32)
        mat = sapien.render.RenderMaterial(base_color=[*color[:3], 1.0], roughness=0.6, specular=0.2)
        shape = sapien.render.RenderShapeTriangleMesh(
            vertices, faces, _flat_normals(vertices, faces), np.zeros((len(vertices), 2), np.float32), mat
        )
        body = sapien.render.RenderBodyComponent()
        body.attach(shape)
        entity.add_component(body)
    if body_type == "static":
        component = physx.PhysxRigidStaticComponent()
    elif body_type == "dynamic":
        component = physx.PhysxRigidDynamicComponent()
    else:
        raise ValueError(f"unknown body_type {body_type!r}; valid choices: static, dynamic")
    scale = np.ones(3, dtype=np.float32)
    for piece in convex_pieces:
        shape = physx.PhysxCollisionShapeConvexMesh(np.ascontiguousarray(piece, dtype=np.float32), scale, material)
        shape.set_density(density)
        component.attach(shape)
    entity.add_component(component)
    if pose is not None:
        entity.pose = pose
    scene.add_entity(entity)
    return entity
