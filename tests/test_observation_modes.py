"""The camera observation modes checked against the scene's geometry: depth against the table plane, segmentation
against the peg's box, point clouds against back-projected depth, and the sampler of fixed-size clouds."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from sapien import physx

import kitbench  # noqa: F401
from kitbench.envs.features import observation_features, observation_frame
from kitbench.envs.pointcloud import PointSampler
from kitbench.envs.tabletop import DEFAULT_POINTCLOUD_RANGE
from kitbench.errors import KitbenchError
from kitbench.geometry import quat_to_matrix
from kitbench.sim.scene import set_actor_pose
from kitbench.tasks.lift_peg_upright import PEG_HALF_LENGTH, PEG_HALF_WIDTH

PEG_TASK = "kitbench/LiftPegUpright-v1"
KITS_TASK = "kitbench/AssemblingKits-v1"
ALL_TEXTURES = "rgb+depth+segmentation"
PEG_HALF = np.array([PEG_HALF_LENGTH, PEG_HALF_WIDTH, PEG_HALF_WIDTH])

# Depth is read from a float32 position buffer: at the farthest table pixel (~1.3 m) float32 resolves ~0.1 um, so
# 2 mm only allows for the camera pose and intrinsics being reported as float32 and for a pixel centre that falls
# on a triangle edge; a depth off by a texel or a wrong convention (ray length, normalised depth) is off by cm.
DEPTH_TOLERANCE = 0.002
# The renderer samples each pixel at its centre, as the ray cast does: only pixels whose centre lies within float
# rounding of the box's outline can disagree, a few out of the peg's hundreds of pixels.
MIN_PEG_IOU = 0.95
# A peg point is interpolated on the peg's faces from float32 vertices; 2 mm admits that and nothing else (the
# peg is 5 cm wide, so a point of the table or the gripper labelled as the peg lies cm away).
SURFACE_TOLERANCE = 0.002
# The cloud and the back-projection both start from the same float32 depth; they differ by float32 rounding of
# the pose (~1e-7 relative, under 1 um at 1.5 m). 1 mm is below the spacing of neighbouring pixels' points (2 mm and
# more in both tasks' cameras), so a cloud shifted by a pixel or in the wrong frame fails.
CLOUD_TOLERANCE = 0.001


# -- helpers --------------------------------------------------------------------------------------
def _reset(task: str, obs_mode: str, seed: int, **kwargs):
    env = gym.make(task, obs_mode=obs_mode, **kwargs)
    obs, _ = env.reset(seed=seed)
    return env, obs


def _rays(params: dict, height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """The camera's centre (3,) and, for every pixel, the world direction (H, W, 3) of the ray through the pixel's
    centre (col + 0.5, row + 0.5), scaled so that one unit along it is one metre along the viewing axis: the point
    at z-depth d is centre + d * direction."""
    k = params["intrinsic_cv"].astype(np.float64)
    ext = params["extrinsic_cv"].astype(np.float64)
    rotation, translation = ext[:, :3], ext[:, 3]
    centre = -rotation.T @ translation
    cols, rows = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    pixels = np.stack([cols, rows, np.ones_like(cols)], axis=-1)
    in_camera = pixels @ np.linalg.inv(k).T  # OpenCV camera frame, z = 1
    return centre, in_camera @ rotation  # rows of R^T @ v: camera to world


def _toss_peg(env, seed: int) -> dict:
    """Teleport the peg to a seeded random orientation in the air between the camera and the raised arm, and step
    once (holding the arm still): the observation then shows the peg in a general pose that nothing occludes, as
    `peg.pose` now gives it (it fell ~1 cm during the step)."""
    rng = np.random.default_rng(seed)
    quaternion = rng.normal(size=4)
    position = [rng.uniform(0.17, 0.22), rng.uniform(-0.08, 0.08), rng.uniform(0.13, 0.18)]
    set_actor_pose(env.unwrapped.peg, position, quaternion / np.linalg.norm(quaternion))
    obs, *_ = env.step(np.zeros(env.action_space.shape, dtype=np.float32))
    return obs


def _table_top(env) -> float:
    """The height of the table's top face, read off its collision box in the scene."""
    table = next(e for e in env.unwrapped.scene.entities if e.name == "table")
    (shape,) = table.find_component_by_type(physx.PhysxRigidStaticComponent).collision_shapes
    return float(shape.local_pose.p[2] + shape.half_size[2] + table.pose.p[2])


def _box_ray_depth(centre: np.ndarray, directions: np.ndarray, position, quaternion, half) -> np.ndarray:
    """Per ray, the z-depth at which it enters the oriented box (slab method), inf where it misses."""
    rotation = quat_to_matrix(quaternion)
    origin = rotation.T @ (centre - np.asarray(position, dtype=np.float64))
    local = directions @ rotation  # rows of R^T @ d: world to the box's frame
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (-half - origin) / local
        t2 = (half - origin) / local
    near = np.minimum(t1, t2).max(axis=-1)
    far = np.maximum(t1, t2).min(axis=-1)
    hit = (far >= near) & (far > 0)
    return np.where(hit, np.maximum(near, 0.0), np.inf)


def _box_surface_distance(points: np.ndarray, position, quaternion, half) -> np.ndarray:
    """Unsigned distance of each point (N, 3) to the surface of the oriented box."""
    rotation = quat_to_matrix(quaternion)
    local = (points.astype(np.float64) - np.asarray(position, dtype=np.float64)) @ rotation
    excess = np.abs(local) - half
    outside = np.linalg.norm(np.maximum(excess, 0.0), axis=-1)
    inside = np.minimum(excess.max(axis=-1), 0.0)
    return np.abs(outside + inside)


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / (a | b).sum())


def _expected_cloud(obs: dict, camera_names, max_depth: float) -> dict[str, np.ndarray]:
    """The cloud built independently from an `rgb+depth+segmentation` observation: each pixel back-projected from
    its depth with the reported intrinsics and extrinsics, w = 1 where 0 < depth <= max_depth, in camera then
    row-major pixel order."""
    xyz, w, rgb, segmentation = [], [], [], []
    for name in camera_names:
        data, params = obs["sensor_data"][name], obs["sensor_param"][name]
        depth = data["depth"][..., 0].astype(np.float64)
        centre, directions = _rays(params, *depth.shape)
        xyz.append((centre + depth[..., None] * directions).reshape(-1, 3))
        w.append(((depth > 0) & (depth <= max_depth)).reshape(-1))
        rgb.append(data["rgb"].reshape(-1, 3))
        segmentation.append(data["segmentation"].reshape(-1, 1))
    return {
        "xyz": np.concatenate(xyz),
        "w": np.concatenate(w),
        "rgb": np.concatenate(rgb),
        "segmentation": np.concatenate(segmentation),
    }


def _synthetic_cloud(kept: int, total: int = 200) -> dict[str, np.ndarray]:
    """A cloud of `total` points whose first `kept` (spread through it) have w = 1; every row carries its index in
    x, rgb and segmentation, so a sampled row can be traced to its source."""
    index = np.arange(total)
    keep = np.zeros(total, dtype=bool)
    keep[np.linspace(0, total - 1, kept).astype(int) if kept else []] = True
    xyzw = np.stack([index, index * 2.0, index * 3.0, keep], axis=1).astype(np.float32)
    rgb = np.stack([index % 256, index // 256, np.zeros_like(index)], axis=1).astype(np.uint8)
    return {"xyzw": xyzw, "rgb": rgb, "segmentation": index[:, None].astype(np.uint16)}


# -- depth ----------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("task", "cameras"), [(PEG_TASK, ("base_camera",)), (KITS_TASK, ("base_camera", "hand_camera"))]
)
def test_depth_is_the_distance_to_the_table_along_the_viewing_axis(needs_vulkan, task, cameras):
    seed = 1
    reference_env, reference = _reset(task, ALL_TEXTURES, seed)
    table_id = {n: i for i, n in reference_env.unwrapped.segmentation_id_map.items()}["table"]
    table_z = _table_top(reference_env)
    assert table_z == pytest.approx(0.0, abs=1e-6)  # kitbench.sim.scene: the table top is the plane z = 0
    assert reference_env.unwrapped.camera_names == cameras
    for obs_mode, textures in (("depth", {"depth"}), ("rgbd", {"rgb", "depth"})):
        env, obs = _reset(task, obs_mode, seed)
        for name in cameras:
            data, params = obs["sensor_data"][name], obs["sensor_param"][name]
            assert set(data) == textures
            depth = data["depth"]
            assert depth.shape == (128, 128, 1) and depth.dtype == np.float32
            segmentation = reference["sensor_data"][name]["segmentation"][..., 0]
            # the same seed renders the same scene, so the labels of the reference env apply to these pixels
            np.testing.assert_array_equal(depth, reference["sensor_data"][name]["depth"])
            table = segmentation == table_id
            assert table.sum() > 500, f"{name} sees too little table ({table.sum()} px) for a meaningful check"
            centre, directions = _rays(params, *depth.shape[:2])
            expected = (table_z - centre[2]) / directions[..., 2]  # z-depth at which each ray meets z = table_z
            error = np.abs(depth[..., 0] - expected)[table]
            assert error.max() < DEPTH_TOLERANCE, f"{obs_mode} {name}: table depth off by up to {error.max():.4f} m"
            # a pixel that sees nothing reads 0, and only such a pixel
            nothing = segmentation == 0
            np.testing.assert_array_equal(depth[..., 0] == 0, nothing)
            assert (depth[..., 0][~nothing] > 0).all()
        env.close()
    reference_env.close()


# -- segmentation ---------------------------------------------------------------------------------
@pytest.mark.parametrize(("seed", "tossed"), [(0, False), (1, True), (2, True)])
def test_peg_pixels_are_the_projection_of_the_peg_box(needs_vulkan, seed, tossed):
    env, obs = _reset(PEG_TASK, ALL_TEXTURES, seed)
    if tossed:
        obs = _toss_peg(env, seed)
    u = env.unwrapped
    peg_id = {n: i for i, n in u.segmentation_id_map.items()}["peg"]
    segmentation = obs["sensor_data"]["base_camera"]["segmentation"]
    assert segmentation.shape == (128, 128, 1) and segmentation.dtype == np.uint16
    labelled = segmentation[..., 0] == peg_id
    centre, directions = _rays(obs["sensor_param"]["base_camera"], 128, 128)
    pose = u.peg.pose
    hit_depth = _box_ray_depth(centre, directions, pose.p, pose.q, PEG_HALF)
    projected = np.isfinite(hit_depth)
    assert projected.sum() > 100  # the peg lies in view
    # Nothing stands between the camera and the peg (at seed 0's reset the hand is raised behind it; a tossed peg
    # hangs in front of the hand), so every pixel whose ray meets the box shows the peg.
    assert _iou(labelled, projected) >= MIN_PEG_IOU, f"seed {seed}: IoU {_iou(labelled, projected):.4f}"
    # and the depth of the peg's pixels is where the ray enters the box
    depth = obs["sensor_data"]["base_camera"]["depth"][..., 0]
    both = labelled & projected
    assert np.abs(depth[both] - hit_depth[both]).max() < DEPTH_TOLERANCE
    env.close()


def test_segmentation_ids_are_stable_across_kits(needs_vulkan):
    env = gym.make(KITS_TASK, obs_mode=ALL_TEXTURES)
    u = env.unwrapped
    id_map = u.segmentation_id_map
    assert id_map[0] == "background"
    assert sorted(id_map) == list(range(len(id_map)))
    assert len(set(id_map.values())) == len(id_map)  # one id per name
    names = {n: i for i, n in id_map.items()}
    kits, seen = set(), set()
    for seed in range(4):
        obs, _ = env.reset(seed=seed)
        kits.add(u.episode_index)
        assert u.segmentation_id_map == id_map
        for name in u.camera_names:
            segmentation = obs["sensor_data"][name]["segmentation"]
            assert segmentation.shape == (128, 128, 1) and segmentation.dtype == np.uint16
            ids = set(np.unique(segmentation).tolist())
            assert ids <= set(id_map), f"seed {seed} {name}: ids {sorted(ids - set(id_map))} not in the map"
            seen |= ids
    assert len(kits) > 1  # the seeds built different kits, so the map was checked against more than one
    # the kit and the loose shape are rebuilt every episode and keep their labels
    assert {names["table"], names["kit"], names["obj_to_place"]} <= seen
    # a fresh env of the same task starting from another kit gives the same map, and so do its dataset features
    other = gym.make(KITS_TASK, obs_mode="segmentation")
    other.reset(seed=3)
    assert other.unwrapped.segmentation_id_map == id_map
    feature = observation_features(other)["observation.images.base_camera_segmentation"]
    assert feature["info"]["segmentation_ids"] == {str(i): n for i, n in id_map.items()}
    other.close()
    env.close()


# -- point clouds ---------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("task", "pointcloud_range"), [(PEG_TASK, None), (KITS_TASK, None), (PEG_TASK, 0.7)], ids=["peg", "kits", "peg-0.7"]
)
def test_pointcloud_is_the_back_projected_depth(needs_vulkan, task, pointcloud_range):
    seed = 2
    kwargs = {} if pointcloud_range is None else {"pointcloud_range": pointcloud_range}
    max_depth = DEFAULT_POINTCLOUD_RANGE if pointcloud_range is None else pointcloud_range
    env, obs = _reset(task, "pointcloud", seed, **kwargs)
    u = env.unwrapped
    assert u.pointcloud_range == max_depth
    cloud = obs["pointcloud"]
    n = sum(s.width * s.height for s in u.camera_specs())
    assert cloud["xyzw"].shape == (n, 4) and cloud["xyzw"].dtype == np.float32
    assert cloud["rgb"].shape == (n, 3) and cloud["rgb"].dtype == np.uint8
    assert cloud["segmentation"].shape == (n, 1) and cloud["segmentation"].dtype == np.uint16
    assert "sensor_data" not in obs and set(obs["sensor_param"]) == set(u.camera_names)

    images_env, images = _reset(task, ALL_TEXTURES, seed)
    expected = _expected_cloud(images, u.camera_names, max_depth)
    w = cloud["xyzw"][:, 3]
    assert set(np.unique(w).tolist()) <= {0.0, 1.0}
    np.testing.assert_array_equal(w > 0, expected["w"])  # w = 0 exactly where depth is 0 or beyond range
    kept = expected["w"]
    assert kept.sum() > 1000
    error = np.linalg.norm(cloud["xyzw"][kept, :3] - expected["xyz"][kept], axis=1)
    assert error.max() < CLOUD_TOLERANCE, f"cloud off the back-projected depth by up to {error.max():.5f} m"
    np.testing.assert_array_equal(cloud["rgb"], expected["rgb"])
    np.testing.assert_array_equal(cloud["segmentation"], expected["segmentation"])
    for name in u.camera_names:
        for key, value in images["sensor_param"][name].items():
            np.testing.assert_array_equal(obs["sensor_param"][name][key], value)

    depth = np.concatenate([images["sensor_data"][c]["depth"].reshape(-1) for c in u.camera_names])
    assert (depth[w > 0] <= max_depth).all()
    if pointcloud_range is not None:
        # the shorter range dropped points the default one keeps
        assert kept.sum() < ((depth > 0) & (depth <= DEFAULT_POINTCLOUD_RANGE)).sum()

    # the dataset frame of a pointcloud observation has the features' shapes
    features = observation_features(env, points=256)
    frame = observation_frame(env, obs, PointSampler(256, seed))
    for key in ("xyz", "rgb", "segmentation"):
        feature, value = features[f"observation.pointcloud.{key}"], frame[f"observation.pointcloud.{key}"]
        assert value.shape == feature["shape"] and value.dtype == np.dtype(feature["dtype"])
    images_env.close()
    env.close()


@pytest.mark.parametrize(("seed", "tossed"), [(0, False), (1, True)])
def test_peg_points_lie_on_the_peg_surface(needs_vulkan, seed, tossed):
    env, obs = _reset(PEG_TASK, "pointcloud", seed)
    if tossed:
        obs = _toss_peg(env, seed)
    u = env.unwrapped
    peg_id = {n: i for i, n in u.segmentation_id_map.items()}["peg"]
    cloud = obs["pointcloud"]
    peg = (cloud["segmentation"][:, 0] == peg_id) & (cloud["xyzw"][:, 3] > 0)
    assert peg.sum() > 100
    pose = u.peg.pose
    distance = _box_surface_distance(cloud["xyzw"][peg, :3], pose.p, pose.q, PEG_HALF)
    assert distance.max() < SURFACE_TOLERANCE, f"seed {seed}: a peg point lies {distance.max():.4f} m off the peg"
    # and no point labelled as something else lies inside the peg
    others = ~peg & (cloud["xyzw"][:, 3] > 0)
    local = (cloud["xyzw"][others, :3].astype(np.float64) - pose.p) @ quat_to_matrix(pose.q)
    assert not (np.abs(local) < PEG_HALF - SURFACE_TOLERANCE).all(axis=1).any()
    env.close()


# -- the point sampler ----------------------------------------------------------------------------
def test_point_sampler_is_seeded_and_draws_only_kept_points():
    cloud = _synthetic_cloud(kept=120)
    kept_rows = set(np.flatnonzero(cloud["xyzw"][:, 3] > 0).tolist())
    first = PointSampler(50, seed=7).sample(cloud)
    again = PointSampler(50, seed=7).sample(cloud)
    other = PointSampler(50, seed=8).sample(cloud)
    for key in ("xyz", "rgb", "segmentation"):
        np.testing.assert_array_equal(first[key], again[key])
    assert not np.array_equal(first["xyz"], other["xyz"])
    assert first["xyz"].shape == (50, 3) and first["xyz"].dtype == np.float32
    assert first["rgb"].shape == (50, 3) and first["rgb"].dtype == np.uint8
    assert first["segmentation"].shape == (50, 1) and first["segmentation"].dtype == np.uint16
    rows = first["segmentation"][:, 0].astype(int)
    assert set(rows.tolist()) <= kept_rows  # only points with w > 0
    assert len(set(rows.tolist())) == 50  # enough kept points: no point twice
    assert (np.diff(rows) > 0).all()  # in the cloud's order
    # xyz, rgb and segmentation of a sampled point come from the same source row
    np.testing.assert_array_equal(first["xyz"], cloud["xyzw"][rows, :3])
    np.testing.assert_array_equal(first["rgb"], cloud["rgb"][rows])
    # a sampler draws anew for every frame
    sampler = PointSampler(50, seed=7)
    sampler.sample(cloud)
    assert not np.array_equal(sampler.sample(cloud)["xyz"], first["xyz"])


def test_point_sampler_repeats_points_when_too_few_are_kept():
    cloud = _synthetic_cloud(kept=5)
    kept_rows = set(np.flatnonzero(cloud["xyzw"][:, 3] > 0).tolist())
    sample = PointSampler(40, seed=0).sample(cloud)
    assert sample["xyz"].shape == (40, 3) and sample["segmentation"].shape == (40, 1)
    rows = sample["segmentation"][:, 0].astype(int)
    assert set(rows.tolist()) <= kept_rows
    assert len(set(rows.tolist())) <= 5
    np.testing.assert_array_equal(sample["xyz"], cloud["xyzw"][rows, :3])


def test_point_sampler_returns_zeros_when_no_point_is_kept():
    sample = PointSampler(32, seed=0).sample(_synthetic_cloud(kept=0))
    expected = {"xyz": ((32, 3), np.float32), "rgb": ((32, 3), np.uint8), "segmentation": ((32, 1), np.uint16)}
    assert set(sample) == set(expected)
    for key, (shape, dtype) in expected.items():
        assert sample[key].shape == shape and sample[key].dtype == dtype
        assert not sample[key].any()


# -- bad input ------------------------------------------------------------------------------------
def test_unknown_obs_mode_is_refused_naming_the_choices():
    with pytest.raises(KitbenchError) as caught:
        gym.make(PEG_TASK, obs_mode="pointclouds")
    message = str(caught.value)
    assert "\n" not in message
    assert "'pointclouds'" in message and "valid choices" in message
    choices = message.split("valid choices:")[1]
    assert "pointcloud" in [c.strip() for c in choices.split(",")]
    assert "rgb+depth+segmentation" in choices


@pytest.mark.parametrize("value", [0, -1, "x", float("nan"), float("inf"), True])
def test_bad_pointcloud_range_is_refused(value):
    with pytest.raises(KitbenchError) as caught:
        gym.make(PEG_TASK, obs_mode="pointcloud", pointcloud_range=value)
    message = str(caught.value)
    assert "\n" not in message
    assert "pointcloud_range" in message and repr(value) in message
