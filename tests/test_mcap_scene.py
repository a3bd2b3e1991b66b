"""MCAP logs show the scene in Foxglove: body geometry attached to `/tf` frames, camera calibrations whose optical
frames project the logged images, sent once and cheap next to the rest of the log."""

from __future__ import annotations

import io

import gymnasium as gym
import numpy as np
import pytest
import sapien
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer
from mcap_protobuf.decoder import DecoderFactory
from PIL import Image

import kitbench  # noqa: F401  (registers the envs)
from kitbench.geometry import pose_to_matrix
from kitbench.policies.baselines import RandomPolicy, ZeroPolicy
from kitbench.policies.expert import ExpertPolicy
from kitbench.recording.rollout import run_episode
from kitbench.recording.scene_geometry import scene_bodies, scene_update
from kitbench.sim.actors import build_convex_actor, cooked_vertices
from kitbench.tasks.lift_peg_upright import PEG_HALF_LENGTH, PEG_HALF_WIDTH

LPU, AK = "LiftPegUpright-v1", "AssemblingKits-v1"
NEW_TOPICS = ("/scene", "/camera/base_camera/calibration", "/camera/hand_camera/calibration")
# What /scene and the calibrations may add to an episode's log. Measured: 17.6 KB for LiftPegUpright (9.4 KB of
# geometry, ~7 KB for the SceneUpdate schema, which MCAP stores in the chunk and again uncompressed in the
# summary) and 22 KB for AssemblingKits, whose scene compresses to 10.8-16.9 KB over 40 kits; state logs of
# expert episodes are 35-45 KB without it.
MAX_OVERHEAD = 26_000


def _record(task: str, policy, seed: int = 0, **make) -> tuple[bytes, gym.Env]:
    env = gym.make(f"kitbench/{task}", **make)
    out = io.BytesIO()
    run_episode(env, policy, seed, mcap=out)
    return out.getvalue(), env


def _decoded(data: bytes) -> dict[str, list]:
    """Every protobuf message decoded with the schema the log itself carries (as Foxglove does):
    topic -> [(log time, message)]."""
    reader = make_reader(io.BytesIO(data), decoder_factories=[DecoderFactory()])
    summary = reader.get_summary()
    assert summary is not None
    topics = [c.topic for c in summary.channels.values() if c.message_encoding == "protobuf"]
    messages: dict[str, list] = {}
    for _, channel, message, proto in reader.iter_decoded_messages(topics, log_time_order=False):
        messages.setdefault(channel.topic, []).append((message.log_time, proto))
    return messages


def _schemas(data: bytes) -> dict[str, str]:
    summary = make_reader(io.BytesIO(data)).get_summary()
    assert summary is not None
    return {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}


def _tf(message) -> dict[str, np.ndarray]:
    """Child frame -> 4x4 world pose of one FrameTransforms message."""
    poses = {}
    for t in message.transforms:
        assert t.parent_frame_id == "world"
        p = [t.translation.x, t.translation.y, t.translation.z]
        q = [t.rotation.w, t.rotation.x, t.rotation.y, t.rotation.z]
        poses[t.child_frame_id] = pose_to_matrix(p, q)
    return poses


def _role(entity) -> str:
    return {kv.key: kv.value for kv in entity.metadata}["role"]


def _size_without(data: bytes, topics) -> int:
    """The log's size had it not carried `topics` (and their schemas): rewritten by the same writer settings."""
    reader = make_reader(io.BytesIO(data))
    summary = reader.get_summary()
    assert summary is not None
    out = io.BytesIO()
    writer = Writer(out, compression=CompressionType.ZSTD)
    writer.start(profile="", library="kitbench")
    schemas: dict[int, int] = {}
    channels: dict[int, int] = {}
    for cid, channel in sorted(summary.channels.items()):
        if channel.topic in topics:
            continue
        if channel.schema_id not in schemas:
            s = summary.schemas[channel.schema_id]
            schemas[channel.schema_id] = writer.register_schema(s.name, s.encoding, s.data)
        channels[cid] = writer.register_channel(channel.topic, channel.message_encoding, schemas[channel.schema_id])
    for _, channel, m in reader.iter_messages(log_time_order=False):
        if channel.id in channels:
            writer.add_message(channels[channel.id], m.log_time, m.data, m.publish_time, m.sequence)
    writer.finish()
    return len(out.getvalue())


@pytest.fixture(scope="module")
def expert_logs():
    """State logs of one expert episode of each task."""
    return {task: _record(task, ExpertPolicy()) for task in (LPU, AK)}


@pytest.mark.parametrize("task", [LPU, AK])
def test_scene_is_sent_once_and_every_entity_follows_a_tf_frame(expert_logs, task):
    data, _ = expert_logs[task]
    assert _schemas(data)["/scene"] == "foxglove.SceneUpdate"
    messages = _decoded(data)
    assert len(messages["/scene"]) == 1
    t0, scene = messages["/scene"][0]
    assert t0 == 0
    frames = [set(_tf(m)) for _, m in messages["/tf"]]
    ids = [e.id for e in scene.entities]
    assert len(ids) == len(set(ids))
    for entity in scene.entities:
        # in every /tf message, so Foxglove places the entity at every time; locked to it, so it moves with it
        assert all(entity.frame_id in f for f in frames), entity.frame_id
        assert entity.frame_locked and entity.lifetime.seconds == entity.lifetime.nanos == 0
        assert len(entity.cubes) + len(entity.triangles) + len(entity.spheres) + len(entity.cylinders) > 0
        for tri in entity.triangles:
            assert len(tri.indices) % 3 == 0 and max(tri.indices) < len(tri.points)


@pytest.mark.parametrize("task", [LPU, AK])
def test_robot_has_an_entity_per_link_with_geometry(expert_logs, task):
    data, env = expert_logs[task]
    ((_, scene),) = _decoded(data)["/scene"]
    entities = {e.id: e for e in scene.entities}
    links = [link.name for link in env.unwrapped.robot.articulation.links]
    drawn = [name for name in links if name in entities]
    # every link but the flange and the TCP, which are frames without a body
    assert set(links) - set(drawn) == {"panda_link8", "panda_hand_tcp"}
    for name in drawn:
        entity = entities[name]
        assert _role(entity) == "link"
        if "finger" in name:
            assert len(entity.cubes) == 4  # the fingertip's collision boxes
        else:
            assert len(entity.triangles) == 1 and 4 <= len(entity.triangles[0].points) <= 64


def test_peg_entity_is_the_peg_box(expert_logs):
    data, _ = expert_logs[LPU]
    ((_, scene),) = _decoded(data)["/scene"]
    (peg,) = [e for e in scene.entities if e.id == "peg"]
    (cube,) = peg.cubes
    size = [cube.size.x, cube.size.y, cube.size.z]
    np.testing.assert_allclose(size, [2 * PEG_HALF_LENGTH, 2 * PEG_HALF_WIDTH, 2 * PEG_HALF_WIDTH], atol=1e-6)
    np.testing.assert_allclose(size, [0.24, 0.05, 0.05], atol=1e-6)
    assert (cube.pose.position.x, cube.pose.position.y, cube.pose.position.z) == (0, 0, 0)
    assert cube.pose.orientation.w == pytest.approx(1.0)


def _points(entity) -> np.ndarray:
    return np.array([[p.x, p.y, p.z] for t in entity.triangles for p in t.points])


def test_assembling_kits_shows_the_board_its_seated_shapes_and_the_loose_shape(expert_logs):
    data, env = expert_logs[AK]
    u = env.unwrapped
    ((_, scene),) = _decoded(data)["/scene"]
    entities = {e.id: e for e in scene.entities}
    seated = {f"in_place_{i}" for i in u.episode.obj_in_place}
    assert {"table", "kit", "obj_to_place"} | seated <= set(entities)
    # the board spans its outline and height (its frame is its pose in /tf)
    board = _points(entities["kit"])
    spec = u.episodes.board
    np.testing.assert_allclose(board.max(0)[:2] - board.min(0)[:2], spec.size, atol=1e-3)
    assert board[:, 2].max() == pytest.approx(spec.top, abs=1e-3)
    # the loose shape is the hull PhysX collides with (to the mesh grid; hulls over 64 vertices simplified)
    exact = np.concatenate([cooked_vertices(s) for s in u.obj_body.collision_shapes])
    shape = _points(entities["obj_to_place"])
    np.testing.assert_allclose(shape.min(0), exact.min(0), atol=1e-3)
    np.testing.assert_allclose(shape.max(0), exact.max(0), atol=1e-3)
    assert _role(entities["obj_to_place"]) == "dynamic"
    assert all(_role(entities[name]) == "static" for name in {"table", "kit"} | seated)


@pytest.mark.parametrize("task", [LPU, AK])
def test_scene_geometry_adds_little_to_a_state_log(expert_logs, task):
    data, _ = expert_logs[task]
    overhead = len(data) - _size_without(data, NEW_TOPICS)
    assert 0 < overhead < MAX_OVERHEAD, overhead


def _calibration_and_image(messages, env, camera):
    """The camera's calibration, checked against its spec (the pinhole SAPIEN renders: square pixels, the
    principal point at the image centre), and its first image."""
    ((t, calibration),) = messages[f"/camera/{camera}/calibration"]
    assert t == 0 and calibration.frame_id == camera
    spec = next(s for s in env.unwrapped.camera_specs() if s.name == camera)
    f = spec.height / 2 / np.tan(spec.fov / 2)
    k = np.array(calibration.K).reshape(3, 3)
    np.testing.assert_allclose(k, [[f, 0, spec.width / 2], [0, f, spec.height / 2], [0, 0, 1]], rtol=1e-5)
    np.testing.assert_allclose(np.array(calibration.P).reshape(3, 4), np.hstack([k, np.zeros((3, 1))]))
    np.testing.assert_allclose(np.array(calibration.R).reshape(3, 3), np.eye(3))
    assert calibration.distortion_model == "plumb_bob" and list(calibration.D) == [0.0] * 5
    _, image = messages[f"/camera/{camera}"][0]
    assert image.frame_id == camera
    rgb = np.asarray(Image.open(io.BytesIO(image.data)).convert("RGB"))
    assert (calibration.width, calibration.height) == (rgb.shape[1], rgb.shape[0]) == (spec.width, spec.height)
    return k, rgb


def test_calibration_projects_the_peg_onto_its_image(needs_vulkan):
    """The base camera's calibration and optical frame put the peg's red half where the image shows it."""
    data, env = _record(LPU, ZeroPolicy(), seed=3, obs_mode="rgb", max_episode_steps=2)
    assert _schemas(data)["/camera/base_camera/calibration"] == "foxglove.CameraCalibration"
    messages = _decoded(data)
    k, rgb = _calibration_and_image(messages, env, "base_camera")
    tf = _tf(messages["/tf"][0][1])
    camera = tf["base_camera"]
    # optical axes: z along the view (from the eye at (0.3, 0, 0.6) towards its target), y down the image
    view = np.array([-0.1, 0, 0.1]) - np.array([0.3, 0, 0.6])
    np.testing.assert_allclose(camera[:3, 2], view / np.linalg.norm(view), atol=1e-5)
    assert camera[2, 1] < 0
    colour = rgb.astype(int)
    red = (colour[..., 0] > colour[..., 1] + 40) & (colour[..., 0] > colour[..., 2] + 40)
    assert red.sum() > 20
    # the centre of the peg's red (+x) half's top face, through the log's transforms and calibration
    point = tf["peg"] @ [PEG_HALF_LENGTH / 2, 0, 0, 1]
    pixel = k @ (np.linalg.inv(camera) @ point)[:3]
    u_px, v_px = pixel[:2] / pixel[2]
    rows, cols = np.nonzero(red)
    assert abs(cols.mean() + 0.5 - u_px) < 3 and abs(rows.mean() + 0.5 - v_px) < 3, (u_px, v_px)


def test_wrist_camera_frame_moves_with_the_hand(needs_vulkan):
    data, env = _record(AK, RandomPolicy(), obs_mode="rgb", max_episode_steps=4)
    messages = _decoded(data)
    for camera in ("base_camera", "hand_camera"):
        _calibration_and_image(messages, env, camera)
    wrist = next(s for s in env.unwrapped.camera_specs() if s.name == "hand_camera")
    assert wrist.mount is not None
    poses = [_tf(m) for _, m in messages["/tf"]]
    assert len(poses) == 5
    hand = [p[wrist.mount] for p in poses]
    assert np.linalg.norm(hand[-1][:3, 3] - hand[0][:3, 3]) > 1e-3  # the hand moved
    relative = [np.linalg.inv(p[wrist.mount]) @ p["hand_camera"] for p in poses]
    for r in relative[1:]:
        np.testing.assert_allclose(r, relative[0], atol=1e-5)
    np.testing.assert_allclose(relative[0][:3, 3], wrist.position, atol=1e-5)
    # SAPIEN's camera looks along its x axis: the optical z axis is the mount's x axis
    mount = pose_to_matrix(wrist.position, wrist.quaternion)
    np.testing.assert_allclose(relative[0][:3, 2], mount[:3, 0], atol=1e-5)


def test_every_collision_shape_kind_becomes_a_primitive_of_its_size():
    """Boxes, spheres, capsules and cylinders as Foxglove primitives at their local poses, convex meshes as
    triangles; planes are left out and a name taken twice gets a suffix."""
    scene = sapien.Scene([sapien.physx.PhysxCpuSystem()])
    ground = scene.create_actor_builder()
    ground.add_plane_collision(sapien.Pose(q=[0.7071068, 0, -0.7071068, 0]))
    ground.build_static(name="ground")
    builder = scene.create_actor_builder()
    builder.add_box_collision(sapien.Pose([0.1, 0, 0]), half_size=[0.01, 0.02, 0.03])
    builder.add_sphere_collision(sapien.Pose([0, 0.1, 0]), radius=0.02)
    builder.add_capsule_collision(sapien.Pose([0, 0, 0.1]), radius=0.01, half_length=0.05)
    builder.add_cylinder_collision(sapien.Pose([0, 0, -0.1]), radius=0.03, half_length=0.04)
    builder.build(name="thing")
    corners = np.array([[x, y, z] for x in (0, 0.1) for y in (0, 0.1) for z in (0, 0.1)])
    build_convex_actor(scene, "thing", [corners], None, (1, 1, 1, 1), "static", sapien.physx.PhysxMaterial(1, 1, 0))
    bodies = scene_bodies(scene)
    assert [(b.frame, b.role) for b in bodies] == [("thing", "dynamic"), ("thing_1", "static")]
    thing, block = scene_update(bodies).entities
    (cube,) = thing.cubes
    assert [cube.size.x, cube.size.y, cube.size.z] == pytest.approx([0.02, 0.04, 0.06])
    assert cube.pose.position.x == pytest.approx(0.1)
    sphere, cap_a, cap_b = thing.spheres
    assert sphere.size.x == pytest.approx(0.04) and sphere.pose.position.y == pytest.approx(0.1)
    capsule, cylinder = thing.cylinders
    # PhysX's x axis along Foxglove's z: the capsule's end spheres sit 5 cm either side of its centre along x
    assert [capsule.size.x, capsule.size.z] == pytest.approx([0.02, 0.1]) and capsule.top_scale == 1
    assert sorted(s.pose.position.x for s in (cap_a, cap_b)) == pytest.approx([-0.05, 0.05])
    assert all(s.pose.position.z == pytest.approx(0.1) for s in (cap_a, cap_b))
    q = capsule.pose.orientation
    axis = pose_to_matrix([0, 0, 0], [q.w, q.x, q.y, q.z])[:3, 2]
    np.testing.assert_allclose(np.abs(axis), [1, 0, 0], atol=1e-6)
    assert [cylinder.size.x, cylinder.size.z] == pytest.approx([0.06, 0.08])
    assert cylinder.pose.position.z == pytest.approx(-0.1)
    (tri,) = block.triangles
    points = np.array([[p.x, p.y, p.z] for p in tri.points])
    assert len(points) == 8 and len(tri.indices) == 36  # the cube's corners, 12 triangles
    np.testing.assert_allclose(points.min(0), 0, atol=1e-4)
    np.testing.assert_allclose(points.max(0), 0.1, atol=1e-4)
