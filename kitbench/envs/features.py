"""The LeRobot features of a kitbench env: the names, types and shapes of its observations and actions.

Defined once, from the env itself, and used by the recorder (a dataset's schema and frames), the runner of trained
lerobot policies (does the checkpoint fit the env? what does it read?) and the LeRobot env plugin
(`--env.type=kitbench`). Shapes follow LeRobot's dataset convention: images (height, width, channels).

Per camera, each of the obs mode's textures (`kitbench.envs.modalities`, with LeRobot's own naming of depth
cameras, `<camera>_depth`, as its robots' depth streams):
- `observation.images.<camera>`: rgb, video (H, W, 3) uint8;
- `observation.images.<camera>_depth`: depth, a LeRobot depth video (H, W, 1) float32 metres along the viewing
  axis, 0 where the pixel sees nothing; stored quantised (`DEPTH_ENCODING`);
- `observation.images.<camera>_segmentation`: segmentation, a lossless 16-bit PNG image (H, W, 1) uint16 of the
  env's stable ids (`segmentation_id_map`, kept in the feature's `info`).
With any texture, the camera's parameters, every frame, under ManiSkill's names (`CAMERA_PARAMS`):
- `observation.sensor_param.<camera>.intrinsic_cv` (9,), `.extrinsic_cv` (12,), `.cam2world_gl` (16,) float32: the
  env's 3x3, 3x4 and 4x4 matrices row by row.
obs_mode `pointcloud`: `observation.pointcloud.xyz` (N, 3) float32 metres, world frame, `.rgb` (N, 3) uint8 and
`.segmentation` (N, 1) uint16, N points sampled per frame (`kitbench.envs.pointcloud`); no camera parameters, as
its points are already in the world frame and do not say which camera saw them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kitbench.control.controllers import controller_class
from kitbench.envs.modalities import TEXTURES, texture_of
from kitbench.envs.modes import POINTCLOUD, camera_textures
from kitbench.envs.pointcloud import DEFAULT_POINTS, PointSampler
from kitbench.envs.tabletop import POSE_NAMES

__all__ = [
    "CAMERA_PARAMS",
    "DEPTH_ENCODING",
    "POSE_NAMES",
    "SENSOR_PARAM",
    "action_feature",
    "action_names",
    "as_loaded",
    "modality",
    "obs_mode_for",
    "observation_features",
    "observation_frame",
    "vector",
]

# The prefix of the point cloud's features (a camera texture's name is `observation.images.<camera><suffix>`,
# `kitbench.envs.modalities`).
POINTCLOUD_PREFIX = "observation.pointcloud."
# The prefix of a camera's parameters: `observation.sensor_param.<camera>.<name>`, `<camera>` as in its images.
SENSOR_PARAM = "observation.sensor_param."


@dataclass(frozen=True)
class CameraParam:
    """One of a camera's parameters as `TabletopEnv` reports it in `obs["sensor_param"][<camera>]`: a matrix, stored
    flat, row by row. LeRobot 0.6.1 keeps a 2-D feature but cannot edit or merge a dataset that has one
    (`lerobot-edit-dataset` delete_episodes and split, `aggregate_datasets`, and so `kitbench merge`, fail on it)."""

    shape: tuple[int, int]  # the matrix's; `.reshape(shape)` gives it back
    info: dict  # its conventions, kept in the feature's info (meta/info.json)
    description: str  # what the dataset card says it holds

    def feature(self) -> dict:
        rows, cols = self.shape
        return {
            "dtype": "float32",
            "shape": (rows * cols,),
            "names": [f"r{r}c{c}" for r in range(rows) for c in range(cols)],
            "info": {**self.info, "matrix": [rows, cols]},
        }


OPENCV_AXES = "OpenCV camera axes: x right, y down, z forward"
# ManiSkill's three, every frame: a camera on the robot (AssemblingKits' hand camera) moves with the arm.
CAMERA_PARAMS = {
    "intrinsic_cv": CameraParam(
        (3, 3),
        {"unit": "pixel", "axes": "opencv"},
        f"camera matrix K (3x3, row by row), pixels, {OPENCV_AXES}; pixel (column, row) is centred at "
        "(column + 0.5, row + 0.5)",
    ),
    "extrinsic_cv": CameraParam(
        (3, 4),
        {"unit": "m", "transform": "world to camera", "axes": "opencv"},
        f"world to camera [R | t] (3x4, row by row; x_camera = R x_world + t), metres, {OPENCV_AXES}",
    ),
    "cam2world_gl": CameraParam(
        (4, 4),
        {"unit": "m", "transform": "camera to world", "axes": "opengl"},
        "camera to world pose (4x4, row by row), metres, OpenGL camera axes as SAPIEN's (x right, y up, z backward)",
    ),
}

# LeRobot's depth quantiser (`DepthEncoderConfig`): 12-bit codes in a lossless HEVC stream. Linear over 0-8.19 m,
# each code is 2 mm, so a stored depth is within 1 mm of the rendered one (LeRobot's default, logarithmic over
# 0.01-10 m, rounds within 0.7 mm at 0.5 m and 1.7 mm at 7 m, and reads a pixel that sees nothing, 0, back as
# 1 cm). Depth beyond 8.19 m is stored as 8.19: every camera of both tasks sees the table within 1.3 m and the
# farthest floor at 7.6 m.
# x265 reports its statistics on every file at its own log level, which libav's does not govern.
DEPTH_ENCODING = {
    "depth_min": 0.0,
    "depth_max": 8.19,
    "use_log": False,
    "extra_options": {"x265-params": "lossless=1:log-level=error"},
}

STATE = "observation.state"
ENVIRONMENT_STATE = "observation.environment_state"
IMAGES = "observation.images."


def vector(names, dtype: str = "float32") -> dict:
    return {"dtype": dtype, "shape": (len(names),), "names": list(names)}


def observation_features(env, obs_mode: str | None = None, points: int = DEFAULT_POINTS) -> dict[str, dict]:
    """`observation.state`, `observation.environment_state` and what `obs_mode` (default: the env's own) adds:
    camera features by texture, or the point cloud's (`points` per frame). Any env of the task and robot gives
    the same features for a mode: the cameras are read off their specs, so a state env needs no renderer."""
    u = env.unwrapped
    obs_mode = u.obs_mode if obs_mode is None else obs_mode
    features = {STATE: vector(u.robot_state_names), ENVIRONMENT_STATE: vector(u.environment_state_names())}
    textures = camera_textures(obs_mode)
    # the id table of segmentations (a point cloud's too), in the features' info
    ids = (
        {"segmentation_ids": {str(i): n for i, n in u.segmentation_id_map.items()}}
        if "segmentation" in textures
        else {}
    )
    if obs_mode == POINTCLOUD:
        features[POINTCLOUD_PREFIX + "xyz"] = {
            "dtype": "float32",
            "shape": (points, 3),
            "names": None,
            "info": {"unit": "m", "frame": "world"},
        }
        features[POINTCLOUD_PREFIX + "rgb"] = {"dtype": "uint8", "shape": (points, 3), "names": None}
        features[POINTCLOUD_PREFIX + "segmentation"] = {
            "dtype": "uint16",
            "shape": (points, 1),
            "names": None,
            "info": ids,
        }
        return features
    for spec in u.camera_specs():
        for texture in TEXTURES.values():
            if texture.name in textures:
                features[IMAGES + spec.name + texture.suffix] = texture.feature(spec.height, spec.width, ids)
        if textures:
            for name, param in CAMERA_PARAMS.items():
                features[f"{SENSOR_PARAM}{spec.name}.{name}"] = param.feature()
    return features


def observation_frame(env, obs, sampler: PointSampler | None = None) -> dict[str, np.ndarray]:
    """The dataset values of `observation_features` for the observation `obs` the env just returned: what the
    recorder stores and what a trained policy is fed (`sampler` draws the point cloud's points; obs_mode pointcloud
    only)."""
    u = env.unwrapped
    frame = {STATE: u.robot_state(), ENVIRONMENT_STATE: u.environment_state()}
    if not isinstance(obs, dict):  # obs_mode state or none: a flat vector, nothing beyond the two states
        return frame
    if "pointcloud" in obs:
        if sampler is None:
            raise ValueError("obs_mode pointcloud needs a PointSampler to draw a frame's points")
        for name, value in sampler.sample(obs["pointcloud"]).items():
            frame[POINTCLOUD_PREFIX + name] = value
        return frame
    for camera, data in obs.get("sensor_data", {}).items():
        for texture in TEXTURES.values():
            if texture.name in data:
                frame[IMAGES + camera + texture.suffix] = data[texture.name]
        params = obs["sensor_param"][camera]
        for name in CAMERA_PARAMS:
            frame[f"{SENSOR_PARAM}{camera}.{name}"] = params[name].reshape(-1)
    return frame


def modality(name: str) -> str | None:
    """What a dataset feature holds of an obs mode: rgb, depth, segmentation or pointcloud; None for the rest."""
    if name.startswith(POINTCLOUD_PREFIX):
        return POINTCLOUD
    texture = texture_of(name, IMAGES)
    return None if texture is None else texture.name


def obs_mode_for(features) -> str:
    """The obs mode whose observations hold the dataset features named in `features` (keys): `pointcloud` for a
    point cloud, else the cameras' textures, rgb with depth spelled `rgbd`; `rgb` for camera parameters without a
    texture (any camera mode has them); `state` for none."""
    found = {modality(name) for name in features} - {None}
    if POINTCLOUD in found:
        return POINTCLOUD
    if not found:
        return "rgb" if any(name.startswith(SENSOR_PARAM) for name in features) else "state"
    if found == {"rgb", "depth"}:
        return "rgbd"
    return "+".join(t for t in TEXTURES if t in found)


def as_loaded(frame: dict[str, np.ndarray], depth_unit: str = "mm") -> dict[str, np.ndarray]:
    """A frame in the layout stock `LeRobotDataset` returns it, as numpy: images channels first, rgb as float32 in
    [0, 1], depth as float32 in `depth_unit` (LeRobot's `depth_output_unit`, "mm" by default), segmentation ids as
    float32, point cloud colours and ids as int64; what a policy trained on the dataset must be fed."""
    out = {}
    for name, value in frame.items():
        texture = texture_of(name, IMAGES)
        if texture is None:  # vectors, point clouds and camera parameters
            out[name] = value.astype(np.int64) if value.dtype.kind in "ui" else value
        else:
            out[name] = texture.loaded(value, depth_unit)
    return out


def action_names(env) -> list[str]:
    """One name per action entry: the arm part of the env's control mode (`Controller.action_names`: joint modes
    name the joints, or `delta_<joint>`), the gripper, then the robot's body joint deltas and base velocities
    (`kitbench.robots.spec`), as the robot's units name them (the SO-101: `shoulder_pan.pos`, ..., `gripper.pos`)."""
    u = env.unwrapped
    spec = u.robot_spec
    arm = controller_class(u.control_mode).action_names(spec.units.joint_names(spec))
    return [*arm, spec.units.gripper_action_name(spec), *spec.extra_action_names]


def action_feature(env) -> dict:
    """The action vector (`action_names`)."""
    return vector(action_names(env))
