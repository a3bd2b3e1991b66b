"""Cameras: declared as specs by tasks and robots, created only in scenes that render.

Images are RGB uint8 (H, W, 3). Depth is float32 (H, W, 1) in metres along the camera's viewing axis
(z-depth, not ray length); pixels that see nothing read 0. Segmentation is the SAPIEN entity id (`per_scene_id`)
each pixel sees, 0 where it sees nothing (the env maps these to its stable ids). Each texture is read off the GPU
(or lavapipe) once per picture, whatever asks for it: `take_picture` costs 5.5 ms for LiftPegUpright's 128x128
camera on 2 CPU cores, and each texture read 0.2 ms more.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import sapien

from kitbench.geometry import look_at, pose_to_matrix

# OpenCV camera axes (x right, y down, z forward) expressed in SAPIEN's camera axes (x forward, y left, z up).
_CV_FROM_SAPIEN = np.array([[0, -1, 0], [0, 0, -1], [1, 0, 0]], dtype=np.float64)
# OpenGL camera axes (x right, y up, z backward) from SAPIEN's.
_GL_TO_SAPIEN = np.array([[0, 0, -1], [-1, 0, 0], [0, 1, 0]], dtype=np.float64)


# The observation cameras' image size (width, height) unless an env's `sensor_configs` asks for another.
OBSERVATION_SIZE = (128, 128)


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


def view(eye, target, fov: float) -> dict[str, Any]:
    """A fixed camera at `eye` looking at `target` with a vertical field of view `fov` (radians), as the
    `sensor_configs` entry that moves a task's camera there."""
    p, q = look_at(eye, target)
    return {"pose": tuple(float(x) for x in (*p, *q)), "fov": float(fov)}


class Camera:
    """A created camera; `capture` renders after the scene's render state was updated."""

    def __init__(self, scene: sapien.Scene, spec: CameraSpec, mount_entity: sapien.Entity | None):
        self.spec = spec
        self._position: np.ndarray | None = None
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
        self._position = None

    def rgb(self) -> np.ndarray:
        color = self._cam.get_picture("Color")  # float32 RGBA in [0, 1]
        return (np.clip(color[..., :3], 0, 1) * 255 + 0.5).astype(np.uint8)

    def position(self) -> np.ndarray:
        """(H, W, 4) float32: each pixel's point in the OpenGL camera frame (x right, y up, z backward) and w,
        the normalised depth, 1 where the pixel sees nothing. Read once per picture (depth and clouds share it)."""
        if self._position is None:
            self._position = self._cam.get_picture("Position")
        return self._position

    def depth(self) -> np.ndarray:
        position = self.position()
        depth = -position[..., 2:3]  # a new array: the cached picture stays as read
        depth[position[..., 3:4] >= 1] = 0.0
        return depth.astype(np.float32)

    def entity_ids(self) -> np.ndarray:
        """(H, W) uint32: the `per_scene_id` of the entity each pixel sees, 0 for none."""
        return self._cam.get_picture("Segmentation")[..., 1]

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


SIZE_KEYS = ("width", "height")
# What `sensor_configs` may set of one camera, as ManiSkill's CameraConfig names them: its image size, vertical field
# of view (radians) and pose (x, y, z, qw, qx, qy, qz: in the world for a fixed camera, on its link for a mounted one).
CAMERA_KEYS = (*SIZE_KEYS, "fov", "pose")


def _check_camera_value(key: str, value) -> object:
    from kitbench.errors import KitbenchError

    if key in SIZE_KEYS:
        if isinstance(value, bool) or not isinstance(value, int) or not 8 <= value <= 4096:
            raise KitbenchError(f"sensor_configs {key} must be a whole number of pixels, 8 to 4096; got {value!r}")
        return value
    if key == "fov":
        if isinstance(value, bool) or not isinstance(value, int | float) or not 0.0 < value < np.pi:
            raise KitbenchError(f"sensor_configs fov must be radians between 0 and pi, got {value!r}")
        return float(value)
    if isinstance(value, sapien.Pose):
        value = (*value.p, *value.q)
    pose = np.asarray(value, dtype=np.float64) if isinstance(value, list | tuple | np.ndarray) else None
    if pose is None or pose.shape != (7,) or not np.isfinite(pose).all() or abs(np.linalg.norm(pose[3:]) - 1) > 1e-3:
        raise KitbenchError(
            f"sensor_configs pose must be x, y, z, qw, qx, qy, qz with a unit quaternion (or a sapien.Pose), "
            f"got {value!r}"
        )
    return tuple(float(x) for x in pose)


def check_sensor_configs(configs, cameras: list[str]) -> dict[str, dict[str, Any]]:
    """ManiSkill's `sensor_configs` as {camera: {key: value}}: `{"width": w, "height": h}` sizes every camera,
    `{camera: {...}}` sets one camera's `CAMERA_KEYS`. A bad key or value is one line naming it and the valid
    choices."""
    from kitbench.errors import KitbenchError

    if configs is None:
        return {}
    if not isinstance(configs, dict):
        raise KitbenchError(f"sensor_configs must be a mapping, got {configs!r}")
    common = {k: v for k, v in configs.items() if k in SIZE_KEYS}
    per_camera = {k: v for k, v in configs.items() if k not in SIZE_KEYS}
    for name, settings in per_camera.items():
        if name not in cameras:
            raise KitbenchError(
                f"sensor_configs: unknown key {name!r}; valid keys: {', '.join((*SIZE_KEYS, *cameras))}"
            )
        if not isinstance(settings, dict) or set(settings) - set(CAMERA_KEYS):
            raise KitbenchError(f"sensor_configs[{name!r}] may set only {', '.join(CAMERA_KEYS)}, got {settings!r}")
    out: dict[str, dict[str, Any]] = {}
    for camera in cameras:
        settings = {**common, **per_camera.get(camera, {})}
        if settings:
            out[camera] = {key: _check_camera_value(key, value) for key, value in settings.items()}
    return out


def configured(spec: CameraSpec, configs: dict[str, dict[str, Any]]) -> CameraSpec:
    """`spec` with what `configs` (from `check_sensor_configs`) sets of it: its size (the field of view kept unless
    set), field of view and pose."""
    settings = configs.get(spec.name, {})
    pose = settings.get("pose")
    return replace(
        spec,
        width=settings.get("width", spec.width),
        height=settings.get("height", spec.height),
        fov=settings.get("fov", spec.fov),
        position=spec.position if pose is None else tuple(pose[:3]),
        quaternion=spec.quaternion if pose is None else tuple(pose[3:]),
    )
