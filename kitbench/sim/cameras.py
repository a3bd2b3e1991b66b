"""Cameras: declared as specs by tasks and robots, created only in scenes that render.

Images are RGB uint8 (H, W, 3). Depth is float32 (H, W, 1) in metres along the camera's viewing axis
(z-depth, not ray length); pixels that see nothing read 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import sapien

from kitbench.geometry import look_at, pose_to_matrix

# OpenCV camera axes (x right, y down, z forward) expressed in SAPIEN's camera axes (x forward, y left, z up).
_CV_FROM_SAPIEN = np.array([[0, -1, 0], [0, 0, -1], [1, 0, 0]], dtype=np.float64)
# OpenGL camera axes (x right, y up, z backward) from SAPIEN's.
_GL_TO_SAPIEN = np.array([[0, 0, -1], [-1, 0, 0], [0, 1, 0]], dtype=np.float64)


@dataclass(frozen=True)
class CameraSpec:
    """A pinhole camera, fixed in the world (mount=None) or rigidly attached to a robot link by name."""

    name: str
    width: int
    height: int
    fov: float  # vertical field of view, radians
    position: tuple[float, float, float]
    quaternion: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    near: float = 0.01
    far: float = 100.0
    mount: str | None = None

    @classmethod
    def looking_at(cls, name, eye, target, width, height, fov, near=0.01, far=100.0) -> CameraSpec:
        p, q = look_at(eye, target)
        return cls(name, width, height, fov, tuple(p), tuple(q), near, far)


class Camera:
    """A created camera; `capture` renders after the scene's render state was updated."""

    def __init__(self, scene: sapien.Scene, spec: CameraSpec, mount_entity: sapien.Entity | None):
        self.spec = spec
        pose = sapien.Pose(spec.position, spec.quaternion)
        if mount_entity is None:
            self._cam = scene.add_camera(spec.name, spec.width, spec.height, spec.fov, spec.near, spec.far)
            self._cam.set_local_pose(pose)
        else:
            self._cam = scene.add_mounted_camera(
                spec.name, mount_entity, pose, spec.width, spec.height, spec.fov, spec.near, spec.far
            )

    def take_picture(self) -> None:
        self._cam.take_picture()

    def rgb(self) -> np.ndarray:
        color = self._cam.get_picture("Color")  # float32 RGBA in [0, 1]
        return (np.clip(color[..., :3], 0, 1) * 255 + 0.5).astype(np.uint8)

    def depth(self) -> np.ndarray:
        position = self._cam.get_picture("Position")  # OpenGL camera frame; w=0 where nothing was hit
        depth = -position[..., 2:3]
        depth[position[..., 3:4] >= 1] = 0.0
        return depth.astype(np.float32)

    def params(self) -> dict[str, np.ndarray]:
        """Intrinsics (OpenCV), world-to-camera extrinsics (OpenCV) and camera-to-world (OpenGL)."""
        cam_to_world = self._cam.get_global_pose()
        t = pose_to_matrix(cam_to_world.p, cam_to_world.q)
        world_to_cv = np.eye(4)
        world_to_cv[:3, :3] = _CV_FROM_SAPIEN @ t[:3, :3].T
        world_to_cv[:3, 3] = -world_to_cv[:3, :3] @ t[:3, 3]
        gl = np.eye(4)
        gl[:3, :3] = t[:3, :3] @ _GL_TO_SAPIEN
        gl[:3, 3] = t[:3, 3]
        return {
            "intrinsic_cv": np.asarray(self._cam.get_intrinsic_matrix(), dtype=np.float32),
            "extrinsic_cv": world_to_cv[:3].astype(np.float32),
            "cam2world_gl": gl.astype(np.float32),
        }
