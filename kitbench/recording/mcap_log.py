"""Per-episode MCAP logs with Foxglove's well-known schemas, so Foxglove renders them as they are.

Topics: `/tf` (FrameTransforms, in the world frame: every robot link, the TCP, every body in the scene, the task's
objects and goals, and each camera's optical frame), `/scene` (SceneUpdate: each body's collision geometry as an
entity attached to its `/tf` frame, sent once at time 0, see `scene_geometry`), `/joint_states` (JointStates),
`/camera/<name>` (CompressedImage, JPEG) with `/camera/<name>/calibration` (CameraCalibration, once at time 0),
and JSON channels `/action`, `/reward` (reward and success) and `/planner` (phase and TCP target).

Times match the dataset's: frame k of an episode has timestamp k * dt, and so do the state the policy saw
(`/tf`, `/joint_states`, `/camera/*`) and the action executed in it (`/action`: the dataset's `executed_action`;
`/planner`). The reward and success the step earned (`next.reward`, `next.success`) are stamped (k + 1) * dt,
when they arrive, and the state after the last step is logged too (one more than the dataset's frames). The
scene's geometry and the camera calibrations do not change within an episode: they are logged once, at time 0.
Every channel numbers its messages from 0 (`sequence`).
"""

from __future__ import annotations

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
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from google.protobuf.timestamp_pb2 import Timestamp
from mcap.writer import CompressionType, Writer
from mcap_protobuf.schema import register_schema
from PIL import Image

WORLD = "world"
JSON_TOPICS = {
    "/action": {"type": "object", "properties": {"action": {"type": "array", "items": {"type": "number"}}}},
    "/reward": {"type": "object", "properties": {"reward": {"type": "number"}, "success": {"type": "boolean"}}},
    "/planner": {
        "type": "object",
        "properties": {"phase": {"type": "string"}, "tcp_target": {"type": "array", "items": {"type": "number"}}},
    },
}


def _stamp(ns: int) -> Timestamp:
    return Timestamp(seconds=ns // 1_000_000_000, nanos=ns % 1_000_000_000)


class EpisodeMcap:
    """Writes one episode; use as a context manager or call `close()`."""

    def __init__(self, target: Path | BinaryIO, cameras: tuple[str, ...] = (), jpeg_quality: int = 90):
        """`target`: a file path (created, and closed by `close()`), or a binary stream the caller owns (left open,
        e.g. a BytesIO whose bytes travel to the dataset writer)."""
        self._owns_file = isinstance(target, str | Path)
        # closed by close(), which the context manager calls
        stream = open(target, "wb") if isinstance(target, str | Path) else target  # noqa: SIM115
        self._file: BinaryIO | None = stream
        self._writer = Writer(stream, compression=CompressionType.ZSTD)
        self._writer.start(profile="", library="kitbench")
        self._jpeg_quality = jpeg_quality
        self._channels: dict[str, int] = {}
        proto = {"/tf": FrameTransforms, "/scene": SceneUpdate, "/joint_states": JointStates}
        for c in cameras:
            proto.update({f"/camera/{c}": CompressedImage, f"/camera/{c}/calibration": CameraCalibration})
        for topic, cls in proto.items():
            schema = register_schema(self._writer, cls)
            self._channels[topic] = self._writer.register_channel(topic, "protobuf", schema)
        for topic, schema_def in JSON_TOPICS.items():
            schema = self._writer.register_schema(topic.strip("/"), "jsonschema", json.dumps(schema_def).encode())
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
        images: dict[str, np.ndarray],
    ) -> None:
        """The scene at `t_ns`. `frames` maps a child frame to its world (position, wxyz quaternion)."""
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
        for camera, rgb in images.items():
            buf = io.BytesIO()
            Image.fromarray(np.ascontiguousarray(rgb)).save(buf, format="JPEG", quality=self._jpeg_quality)
            msg = CompressedImage(timestamp=stamp, frame_id=camera, data=buf.getvalue(), format="jpeg")
            self._write(f"/camera/{camera}", msg.SerializeToString(), t_ns)

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
