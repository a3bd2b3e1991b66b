"""Per-episode MCAP logs with Foxglove's well-known schemas, so Foxglove renders them as they are.

Topics: `/tf` (FrameTransforms, in the world frame: every robot link, the TCP, every body in the scene, the task's
objects and goals, and each camera's optical frame), `/scene` (SceneUpdate: each body's collision geometry as an
entity attached to its `/tf` frame, sent once at time 0, see `scene_geometry`), `/joint_states` (JointStates),
`/camera/<name>` (CompressedImage, JPEG) with `/camera/<name>/calibration` (CameraCalibration, once at time 0),
and JSON channels `/action`, `/reward` (reward and success) and `/planner` (phase and TCP target).

By the obs mode's textures, each camera also has `/camera/<name>/depth` (RawImage `32FC1`, metres along the viewing
axis, 0 where it sees nothing) and `/camera/<name>/segmentation` (CompressedImage, PNG, one colour per id: id 0,
nothing, is black), with `/segmentation_ids` (JSON: id to name) once at time 0. obs_mode pointcloud logs the fused
cloud's kept points as `/pointcloud` (PointCloud in the world frame: x, y, z float32, red, green, blue, alpha and
segmentation), which Foxglove's 3D panel draws over `/scene`.

Times match the dataset's: frame k of an episode has timestamp k * dt, and so do the state the policy saw
(`/tf`, `/joint_states`, `/camera/*`) and the action executed in it (`/action`: the dataset's `executed_action`;
`/planner`). The reward and success the step earned (`next.reward`, `next.success`) are stamped (k + 1) * dt,
when they arrive, and the state after the last step is logged too (one more than the dataset's frames). The
scene's geometry and the camera calibrations do not change within an episode: they are logged once, at time 0.
Every channel numbers its messages from 0 (`sequence`).
"""

from __future__ import annotations

import colorsys
import io
import json
from pathlib import Path
from typing import BinaryIO

import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.JointState_pb2 import JointState
from foxglove_schemas_protobuf.JointStates_pb2 import JointStates
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from google.protobuf.timestamp_pb2 import Timestamp
from mcap.writer import CompressionType, Writer
from mcap_protobuf.schema import register_schema
from PIL import Image

from kitbench.envs.modalities import TEXTURES, Texture

WORLD = "world"
JSON_TOPICS = {
    "/action": {"type": "object", "properties": {"action": {"type": "array", "items": {"type": "number"}}}},
    "/reward": {"type": "object", "properties": {"reward": {"type": "number"}, "success": {"type": "boolean"}}},
    "/planner": {
        "type": "object",
        "properties": {"phase": {"type": "string"}, "tcp_target": {"type": "array", "items": {"type": "number"}}},
    },
}
SEGMENTATION_IDS_TOPIC = "/segmentation_ids"
POINTCLOUD_TOPIC = "/pointcloud"
# One point of `/pointcloud`: x, y, z (float32), red, green, blue, alpha (uint8: Foxglove's "RGBA (separate
# fields)" colouring) and the segmentation id (uint16), padded to 4-byte alignment.
POINT_FIELDS = (
    ("x", "<f4", PackedElementField.FLOAT32),
    ("y", "<f4", PackedElementField.FLOAT32),
    ("z", "<f4", PackedElementField.FLOAT32),
    ("red", "u1", PackedElementField.UINT8),
    ("green", "u1", PackedElementField.UINT8),
    ("blue", "u1", PackedElementField.UINT8),
    ("alpha", "u1", PackedElementField.UINT8),
    ("segmentation", "<u2", PackedElementField.UINT16),
)
POINT_DTYPE = np.dtype([(name, dtype) for name, dtype, _ in POINT_FIELDS] + [("pad", "<u2")])


def segmentation_colors(count: int) -> np.ndarray:
    """(count, 3) uint8: a distinct colour per segmentation id (hues a golden-ratio turn apart, so neighbouring ids
    differ most), black for id 0 (nothing)."""
    colors = [colorsys.hsv_to_rgb((i * 0.618033988749895) % 1.0, 0.75, 0.95) for i in range(count)]
    table = (np.array(colors, dtype=np.float64).reshape(count, 3) * 255 + 0.5).astype(np.uint8)
    table[:1] = 0
    return table


def _stamp(ns: int) -> Timestamp:
    return Timestamp(seconds=ns // 1_000_000_000, nanos=ns % 1_000_000_000)


class EpisodeMcap:
    """Writes one episode; use as a context manager or call `close()`."""

    def __init__(
        self,
        target: Path | BinaryIO,
        cameras: tuple[str, ...] = (),
        textures: frozenset[str] = frozenset({"rgb"}),
        segmentation_ids: dict[int, str] | None = None,
        pointcloud: bool = False,
        jpeg_quality: int = 90,
    ):
        """`target`: a file path (created, and closed by `close()`), or a binary stream the caller owns (left open,
        e.g. a BytesIO whose bytes travel to the dataset writer). `cameras` get a calibration each and a channel per
        texture in `textures` (rgb, depth, segmentation); `segmentation_ids` (id to name) is logged with the first
        state; `pointcloud` adds `/pointcloud`."""
        self._owns_file = isinstance(target, str | Path)
        # closed by close(), which the context manager calls
        stream = open(target, "wb") if isinstance(target, str | Path) else target  # noqa: SIM115
        self._file: BinaryIO | None = stream
        self._writer = Writer(stream, compression=CompressionType.ZSTD)
        self._writer.start(profile="", library="kitbench")
        self._jpeg_quality = jpeg_quality
        self._channels: dict[str, int] = {}
        self._segmentation_ids = segmentation_ids
        self._colors = segmentation_colors(max(segmentation_ids, default=0) + 1 if segmentation_ids else 1)
        proto: dict[str, type] = {"/tf": FrameTransforms, "/scene": SceneUpdate, "/joint_states": JointStates}
        for c in cameras:
            proto[f"/camera/{c}/calibration"] = CameraCalibration
            for texture in TEXTURES.values():
                if texture.name in textures:
                    proto[f"/camera/{c}{texture.mcap_topic}"] = RawImage if texture.mcap == "float" else CompressedImage
        if pointcloud:
            proto[POINTCLOUD_TOPIC] = PointCloud
        for topic, cls in proto.items():
            schema = register_schema(self._writer, cls)
            self._channels[topic] = self._writer.register_channel(topic, "protobuf", schema)
        for topic, schema_def in JSON_TOPICS.items():
            schema = self._writer.register_schema(topic.strip("/"), "jsonschema", json.dumps(schema_def).encode())
            self._channels[topic] = self._writer.register_channel(topic, "json", schema)
        labelled = any(t.mcap == "labels" and t.name in textures for t in TEXTURES.values())
        if segmentation_ids is not None and cameras and labelled:
            topic = SEGMENTATION_IDS_TOPIC
            schema = self._writer.register_schema(
                topic.strip("/"), "jsonschema", json.dumps({"type": "object"}).encode()
            )
            self._channels[topic] = self._writer.register_channel(topic, "json", schema)
        self.messages: dict[str, int] = dict.fromkeys(self._channels, 0)

    def _write(self, topic: str, data: bytes, t_ns: int) -> None:
        sequence = self.messages[topic]
        self._writer.add_message(self._channels[topic], log_time=t_ns, publish_time=t_ns, data=data, sequence=sequence)
        self.messages[topic] = sequence + 1

    def log_scene(self, t_ns: int, scene: SceneUpdate) -> None:
        """The scene's geometry (`scene_geometry.scene_update`), sent once: its entities never expire and follow
        their `/tf` frames, and Foxglove replays a topic's last message when it seeks."""
        stamp = _stamp(t_ns)
        for entity in scene.entities:
            entity.timestamp.CopyFrom(stamp)
        self._write("/scene", scene.SerializeToString(), t_ns)

    def log_calibration(self, t_ns: int, camera: str, intrinsic: np.ndarray, width: int, height: int) -> None:
        """A pinhole camera without distortion whose images carry frame id `camera` (its optical frame in `/tf`)."""
        k = np.asarray(intrinsic, dtype=np.float64).reshape(3, 3)
        p = np.hstack([k, np.zeros((3, 1))])
        msg = CameraCalibration(timestamp=_stamp(t_ns), frame_id=camera, width=width, height=height)
        msg.distortion_model = "plumb_bob"
        msg.D.extend([0.0] * 5)
        msg.K.extend(float(v) for v in k.ravel())
        msg.R.extend(float(v) for v in np.eye(3).ravel())
        msg.P.extend(float(v) for v in p.ravel())
        self._write(f"/camera/{camera}/calibration", msg.SerializeToString(), t_ns)

    def log_state(
        self,
        t_ns: int,
        *,
        frames: dict[str, tuple[np.ndarray, np.ndarray]],
        joint_names,
        qpos,
        qvel,
        cameras: dict[str, dict[str, np.ndarray]],
        pointcloud: dict[str, np.ndarray] | None = None,
    ) -> None:
        """The scene at `t_ns`. `frames` maps a child frame to its world (position, wxyz quaternion); `cameras`
        each camera's textures (the env's `sensor_data`); `pointcloud` the env's fused cloud (its kept points are
        logged)."""
        stamp = _stamp(t_ns)
        tf = FrameTransforms()
        for child, (p, q) in frames.items():
            t = FrameTransform(timestamp=stamp, parent_frame_id=WORLD, child_frame_id=child)
            t.translation.x, t.translation.y, t.translation.z = (float(v) for v in p)
            t.rotation.w, t.rotation.x, t.rotation.y, t.rotation.z = (float(v) for v in q)
            tf.transforms.append(t)
        self._write("/tf", tf.SerializeToString(), t_ns)
        js = JointStates(timestamp=stamp)
        for name, position, velocity in zip(joint_names, qpos, qvel, strict=True):
            js.joints.append(JointState(name=name, position=float(position), velocity=float(velocity)))
        self._write("/joint_states", js.SerializeToString(), t_ns)
        if SEGMENTATION_IDS_TOPIC in self._channels and not self.messages[SEGMENTATION_IDS_TOPIC]:
            ids = {str(i): name for i, name in (self._segmentation_ids or {}).items()}
            self._write(SEGMENTATION_IDS_TOPIC, json.dumps(ids).encode(), t_ns)
        for camera, data in cameras.items():
            for texture in TEXTURES.values():
                if texture.name in data:
                    self._log_texture(texture, camera, stamp, t_ns, data[texture.name])
        if pointcloud is not None:
            self._write(POINTCLOUD_TOPIC, self._pointcloud(stamp, pointcloud).SerializeToString(), t_ns)

    def _log_texture(self, texture: Texture, camera: str, stamp: Timestamp, t_ns: int, value: np.ndarray) -> None:
        """One camera's texture as its class says it travels (`Texture.mcap`)."""
        topic = f"/camera/{camera}{texture.mcap_topic}"
        if texture.mcap == "jpeg":
            self._write_image(topic, camera, stamp, t_ns, value, "jpeg")
        elif texture.mcap == "labels":
            ids = np.minimum(value[..., 0], len(self._colors) - 1)
            self._write_image(topic, camera, stamp, t_ns, self._colors[ids], "png")
        else:  # "float": one channel, 32-bit floats as they are
            plane = np.ascontiguousarray(value[..., 0], dtype="<f4")
            height, width = plane.shape
            msg = RawImage(
                timestamp=stamp, frame_id=camera, width=width, height=height, encoding="32FC1", step=4 * width
            )
            msg.data = plane.tobytes()
            self._write(topic, msg.SerializeToString(), t_ns)

    def _write_image(self, topic: str, camera: str, stamp: Timestamp, t_ns: int, rgb: np.ndarray, fmt: str):
        """An RGB image as a CompressedImage: JPEG for camera pictures, PNG (lossless) for label colours."""
        buf = io.BytesIO()
        image = Image.fromarray(np.ascontiguousarray(rgb))
        if fmt == "jpeg":
            image.save(buf, format="JPEG", quality=self._jpeg_quality)
        else:
            image.save(buf, format="PNG", compress_level=1)
        msg = CompressedImage(timestamp=stamp, frame_id=camera, data=buf.getvalue(), format=fmt)
        self._write(topic, msg.SerializeToString(), t_ns)

    @staticmethod
    def _pointcloud(stamp: Timestamp, cloud: dict[str, np.ndarray]) -> PointCloud:
        """The cloud's kept points (w > 0) as a world-frame PointCloud."""
        kept = cloud["xyzw"][:, 3] > 0
        points = np.zeros(int(kept.sum()), dtype=POINT_DTYPE)
        xyz = cloud["xyzw"][kept, :3]
        points["x"], points["y"], points["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
        rgb = cloud["rgb"][kept]
        points["red"], points["green"], points["blue"] = rgb[:, 0], rgb[:, 1], rgb[:, 2]
        points["alpha"] = 255
        points["segmentation"] = cloud["segmentation"][kept, 0]
        msg = PointCloud(timestamp=stamp, frame_id=WORLD, point_stride=POINT_DTYPE.itemsize, data=points.tobytes())
        msg.pose.orientation.w = 1.0
        offset = 0
        for name, dtype, kind in POINT_FIELDS:
            msg.fields.append(PackedElementField(name=name, offset=offset, type=kind))
            offset += np.dtype(dtype).itemsize
        return msg

    def log_action(self, t_ns: int, action, phase: str | None = None, tcp_target: np.ndarray | None = None) -> None:
        """The action chosen in the state logged at `t_ns`, and the planner's phase and target for it."""
        self._write("/action", json.dumps({"action": [float(a) for a in action]}).encode(), t_ns)
        if phase is not None:
            target = [] if tcp_target is None else [float(v) for v in np.ravel(tcp_target)]
            self._write("/planner", json.dumps({"phase": phase, "tcp_target": target}).encode(), t_ns)

    def log_outcome(self, t_ns: int, reward: float, success: bool) -> None:
        """What the step ending at `t_ns` earned."""
        self._write("/reward", json.dumps({"reward": float(reward), "success": bool(success)}).encode(), t_ns)

    def close(self) -> None:
        if self._file is not None:
            self._writer.finish()
            if self._owns_file:
                self._file.close()
            self._file = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
