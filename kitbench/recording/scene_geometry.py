"""The scene's geometry for Foxglove's 3D panel, read from the SAPIEN scene itself.

Every body with collision geometry (the robot's links, the table, a task's objects and fixtures) becomes one
`foxglove.SceneEntity` attached to the body's own `/tf` frame (`frame_locked`), so the transforms the log records
every step move it and its geometry is sent once. The geometry is what PhysX collides with: boxes, spheres,
capsules and cylinders as Foxglove primitives, convex hulls and triangle meshes as one indexed triangle list per
body. Nothing here knows a task: a new task's actors show up as they are.

Collision rather than visual geometry: the Panda's visual meshes are 10 MB of COLLADA (135k triangles, 16k after
robots/visuals.py decimates them for rendering), its collision hulls 1,000 vertices and 2,000 triangles; and a
state-only scene has no visuals at all. Sizes, zstd-compressed as in the log: the `/scene` message is 9.4 KB for
LiftPegUpright and 10.8-16.9 KB for AssemblingKits (over 40 kits, a board being dozens of convex pieces). With the
SceneUpdate schema (~7 KB: MCAP keeps it in the chunk and again, uncompressed, in the summary) an episode's log
grows by 17.6 KB (LiftPegUpright) and ~22 KB (AssemblingKits), where a state log was 35-45 KB. Building the
update takes ~5 ms a LiftPegUpright episode and ~10 ms an AssemblingKits one, once the Panda's simplified hulls
are cached (the first episode in a process pays ~40 ms).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import sapien
from foxglove_schemas_protobuf.Color_pb2 import Color
from foxglove_schemas_protobuf.CubePrimitive_pb2 import CubePrimitive
from foxglove_schemas_protobuf.CylinderPrimitive_pb2 import CylinderPrimitive
from foxglove_schemas_protobuf.KeyValuePair_pb2 import KeyValuePair
from foxglove_schemas_protobuf.Point3_pb2 import Point3
from foxglove_schemas_protobuf.Pose_pb2 import Pose
from foxglove_schemas_protobuf.SceneEntity_pb2 import SceneEntity
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from foxglove_schemas_protobuf.SpherePrimitive_pb2 import SpherePrimitive
from foxglove_schemas_protobuf.TriangleListPrimitive_pb2 import TriangleListPrimitive
from sapien import physx

from kitbench.geometry import matrix_to_quat, pose_to_matrix

# State-only scenes have no render materials, so colours go by role, the same in every observation mode: links
# grey, the objects a task moves in orange tones and fixtures through the other colours, each in scene order (the
# table first), which tells the kit board from the table and the seated shapes from the board.
LINK_COLOR = (0.85, 0.85, 0.87, 1.0)
COLORS = {
    "static": (
        (0.66, 0.55, 0.42, 1.0),  # wood
        (0.45, 0.52, 0.62, 1.0),  # slate
        (0.30, 0.62, 0.35, 1.0),  # green
        (0.62, 0.36, 0.62, 1.0),  # plum
        (0.85, 0.75, 0.30, 1.0),  # ochre
    ),
    "dynamic": (
        (0.95, 0.50, 0.10, 1.0),  # orange
        (0.80, 0.20, 0.15, 1.0),  # brick
    ),
}
# Mesh vertices are rounded to a 2^-14 m grid (0.06 mm, finer than the 0.11 mm to which PhysX cooks the kit's
# hulls): such doubles end in zero bytes, which zstd drops. LiftPegUpright's scene compresses to 9.4 KB instead
# of 13.1 KB at full precision (a coarser 2^-10 m grid would save only 1.0 KB more).
GRID = 2.0**-14
# Convex hulls with more vertices are simplified to about this many (quadric decimation, then the hull of what is
# left, so the shape stays closed and convex). The Panda's hulls have 79-133 vertices: at 64 they take 9.0 KB
# instead of 15.7 KB and stay within 3.9 mm of PhysX's (at 48: 6.7 KB, 6.4 mm). The kit's pieces have at most 16
# vertices and stay exact; a loose disc (96) moves 0.15 mm.
MAX_HULL_VERTICES = 64
# PhysX capsules and cylinders run along their x axis, Foxglove's cylinders along z: a quarter turn about y.
_Z_TO_X = sapien.Pose(q=[np.sqrt(0.5), 0.0, np.sqrt(0.5), 0.0])


@dataclass(frozen=True)
class Body:
    """A rigid body the log draws: its `/tf` frame (also the entity's id), the SAPIEN entity and its role."""

    frame: str
    entity: sapien.Entity
    role: str  # "link" (of an articulation), "static" or "dynamic"

    def pose(self) -> tuple[np.ndarray, np.ndarray]:
        pose = self.entity.pose
        return pose.p, pose.q


def _shapes(entity: sapien.Entity) -> tuple[str, list]:
    """The entity's role and its drawable collision shapes (a plane is infinite: Foxglove's grid stands in)."""
    for component in entity.components:
        if isinstance(component, physx.PhysxArticulationLinkComponent):
            role = "link"
        elif isinstance(component, physx.PhysxRigidStaticComponent):
            role = "static"
        elif isinstance(component, physx.PhysxRigidDynamicComponent):
            role = "dynamic"
        else:
            continue
        shapes = [s for s in component.collision_shapes if not isinstance(s, physx.PhysxCollisionShapePlane)]
        return role, shapes
    return "", []


def scene_bodies(scene: sapien.Scene) -> list[Body]:
    """Every body in `scene` with something to draw, in scene order; a name taken already gets a `_<k>` suffix."""
    bodies: list[Body] = []
    taken: set[str] = set()
    for entity in scene.entities:
        role, shapes = _shapes(entity)
        if not shapes:
            continue
        base = entity.name or "body"
        frame, k = base, 1
        while frame in taken:
            frame, k = f"{base}_{k}", k + 1
        taken.add(frame)
        bodies.append(Body(frame, entity, role))
    return bodies


def _pose(pose: sapien.Pose) -> Pose:
    out = Pose()
    out.position.x, out.position.y, out.position.z = (float(v) for v in pose.p)
    out.orientation.w, out.orientation.x, out.orientation.y, out.orientation.z = (float(v) for v in pose.q)
    return out


def _color(rgba) -> Color:
    return Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])


def _mesh(shape) -> tuple[np.ndarray, np.ndarray]:
    """A convex or triangle mesh shape's vertices in its body's frame and its triangles (a hull simplified to
    about MAX_HULL_VERTICES)."""
    local = shape.get_local_pose()
    t = pose_to_matrix(local.p, local.q)
    # vertices times the shape's scale: kit pieces are cooked in millimetres and scaled back (sim/actors.py)
    vertices = np.asarray(shape.get_vertices(), dtype=np.float64) * np.asarray(shape.get_scale(), dtype=np.float64)
    vertices = np.ascontiguousarray(vertices @ t[:3, :3].T + t[:3, 3])
    faces = np.ascontiguousarray(np.asarray(shape.get_triangles(), dtype=np.int64).reshape(-1, 3))
    if isinstance(shape, physx.PhysxCollisionShapeConvexMesh) and len(vertices) > MAX_HULL_VERTICES:
        return _simplified_hull(vertices.tobytes(), faces.tobytes())
    return vertices, faces


@functools.lru_cache(maxsize=256)
def _simplified_hull(vertices: bytes, faces: bytes) -> tuple[np.ndarray, np.ndarray]:
    """Cached by content: the robot's hulls are the same every episode, and simplifying them takes ~25 ms."""
    import fast_simplification
    import trimesh

    v = np.frombuffer(vertices, dtype=np.float64).reshape(-1, 3).copy()  # writable, as the simplifier needs
    f = np.frombuffer(faces, dtype=np.int64).reshape(-1, 3).copy()
    # a closed convex triangulation with V vertices has 2V - 4 triangles
    keep = (2 * MAX_HULL_VERTICES - 4) / len(f)
    simplified, _ = fast_simplification.simplify(v.astype(np.float32), f, target_reduction=1.0 - keep)
    hull = trimesh.convex.convex_hull(np.asarray(simplified, dtype=np.float64))
    return np.asarray(hull.vertices, dtype=np.float64), np.asarray(hull.faces, dtype=np.int64)


def _triangles(meshes: list[tuple[np.ndarray, np.ndarray]], color) -> TriangleListPrimitive:
    """All of a body's meshes as one indexed list, its vertices on the GRID and welded: neighbouring kit pieces
    share corners (a board's 422 vertices were 154 distinct ones). Foxglove draws triangle lists flat-shaded, so
    sharing vertices between faces changes nothing on screen; indexed, the Panda is 32 KB of protobuf for
    Foxglove to parse instead of 96 KB (9.1 KB instead of 10.2 KB compressed)."""
    vertices = np.concatenate([v for v, _ in meshes])
    offsets = np.cumsum([0] + [len(v) for v, _ in meshes[:-1]])
    faces = np.concatenate([f + o for (_, f), o in zip(meshes, offsets, strict=True)])
    grid, index = np.unique(np.round(vertices / GRID).astype(np.int64), axis=0, return_inverse=True)
    faces = index.reshape(-1)[faces]
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 2] != faces[:, 0])]
    out = TriangleListPrimitive(pose=_pose(sapien.Pose()), color=_color(color))
    for x, y, z in (grid * GRID).tolist():
        out.points.append(Point3(x=x, y=y, z=z))
    out.indices.extend(faces.ravel().tolist())
    return out


def body_entity(body: Body, color) -> SceneEntity:
    """`body`'s collision geometry, in its frame, following that frame and never expiring."""
    entity = SceneEntity(frame_id=body.frame, id=body.frame, frame_locked=True)
    entity.metadata.append(KeyValuePair(key="role", value=body.role))
    meshes = []
    for shape in _shapes(body.entity)[1]:
        local = shape.get_local_pose()
        if isinstance(shape, physx.PhysxCollisionShapeBox):
            size = [2.0 * float(h) for h in shape.get_half_size()]
            cube = CubePrimitive(pose=_pose(local), color=_color(color))
            cube.size.x, cube.size.y, cube.size.z = size
            entity.cubes.append(cube)
        elif isinstance(shape, physx.PhysxCollisionShapeSphere):
            d = 2.0 * float(shape.get_radius())
            sphere = SpherePrimitive(pose=_pose(local), color=_color(color))
            sphere.size.x = sphere.size.y = sphere.size.z = d
            entity.spheres.append(sphere)
        elif isinstance(shape, physx.PhysxCollisionShapeCapsule | physx.PhysxCollisionShapeCylinder):
            d, half = 2.0 * float(shape.get_radius()), float(shape.get_half_length())
            cylinder = CylinderPrimitive(pose=_pose(local * _Z_TO_X), color=_color(color))
            cylinder.size.x, cylinder.size.y, cylinder.size.z = d, d, 2.0 * half
            cylinder.bottom_scale = cylinder.top_scale = 1.0
            entity.cylinders.append(cylinder)
            if isinstance(shape, physx.PhysxCollisionShapeCapsule):
                for sign in (-1.0, 1.0):
                    cap = SpherePrimitive(pose=_pose(local * sapien.Pose([sign * half, 0.0, 0.0])))
                    cap.color.CopyFrom(_color(color))
                    cap.size.x = cap.size.y = cap.size.z = d
                    entity.spheres.append(cap)
        elif isinstance(shape, physx.PhysxCollisionShapeConvexMesh | physx.PhysxCollisionShapeTriangleMesh):
            meshes.append(_mesh(shape))
    if meshes:
        entity.triangles.append(_triangles(meshes, color))
    return entity


def scene_update(bodies: list[Body]) -> SceneUpdate:
    """One entity per body: links in one colour, other bodies through their role's palette in scene order."""
    update = SceneUpdate()
    seen = dict.fromkeys(COLORS, 0)
    for body in bodies:
        if body.role == "link":
            color = LINK_COLOR
        else:
            palette = COLORS[body.role]
            color = palette[seen[body.role] % len(palette)]
            seen[body.role] += 1
        update.entities.append(body_entity(body, color))
    return update


def optical_frame(extrinsic_cv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World pose (position, wxyz quaternion) of a camera's optical frame (x right, y down, z forward: what
    Foxglove projects images with) from its world-to-camera OpenCV extrinsics (`Camera.params()`)."""
    e = np.asarray(extrinsic_cv, dtype=np.float64)
    rotation = e[:3, :3].T
    return -rotation @ e[:3, 3], matrix_to_quat(rotation)
