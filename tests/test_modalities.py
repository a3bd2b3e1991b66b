"""Depth, segmentation and point clouds through the product: recorded into LeRobot datasets that stock lerobot
loads as the env gave them (and trains on), logged to MCAP, checked by lerobot-doctor, and fed to trained policies
and the LeRobot plugin under the dataset's names and in its layout."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import kitbench
from kitbench.envs.features import DEPTH_ENCODING, as_loaded, obs_mode_for, observation_features, observation_frame
from kitbench.envs.modes import IMAGE_OBS_MODES
from kitbench.envs.pointcloud import PointSampler
from kitbench.errors import KitbenchError
from kitbench.recording.recorder import RecordConfig, record
from tests.lerobot_cli import BIN, OFFLINE, lerobot_train, small_config

TEXTURES = "rgb+depth+segmentation"
POINTS = 256
# Each 12-bit depth code is 2 mm (DEPTH_ENCODING: linear over 0-8.19 m): a stored depth is within half a code.
DEPTH_STEP = DEPTH_ENCODING["depth_max"] / 4095
RECORDINGS = [("LiftPegUpright-v1", TEXTURES), ("LiftPegUpright-v1", "pointcloud")]
RECORDINGS += [("AssemblingKits-v1", TEXTURES), ("AssemblingKits-v1", "pointcloud")]


def _load(root: Path, **kwargs):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    return LeRobotDataset("kitbench/test", root=root, **kwargs)


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    """One expert episode per (task, obs mode), MCAP logs included; and a LiftPegUpright rgb one to compare with."""
    base = tmp_path_factory.mktemp("modalities")
    out = {}
    for task, mode in [*RECORDINGS, ("LiftPegUpright-v1", "rgb")]:
        root = base / f"{task}_{mode}"
        record(
            RecordConfig.of(
                task=task,
                episodes=1,
                out=root,
                seed=3,
                obs_mode=mode,
                control_mode="pd_joint_pos",
                pointcloud_points=POINTS,
            ),
            progress=False,
        )
        out[task, mode] = root
    return out


def test_each_mode_stores_its_features_under_lerobot_names():
    env = gym.make("kitbench/AssemblingKits-v1", obs_mode="state")
    cams = ("base_camera", "hand_camera")
    expected = {
        "rgb": [f"observation.images.{c}" for c in cams],
        "depth": [f"observation.images.{c}_depth" for c in cams],
        "segmentation": [f"observation.images.{c}_segmentation" for c in cams],
        "pointcloud": [f"observation.pointcloud.{k}" for k in ("xyz", "rgb", "segmentation")],
    }
    # every texture mode keeps each camera's parameters; a point cloud, in the world frame, none
    params = [
        f"observation.sensor_param.{c}.{k}" for c in cams for k in ("intrinsic_cv", "extrinsic_cv", "cam2world_gl")
    ]
    for mode in IMAGE_OBS_MODES:
        features = observation_features(env, mode, points=POINTS)
        extra = set(features) - {"observation.state", "observation.environment_state"}
        parts = ["pointcloud"] if mode == "pointcloud" else ["rgb", "depth"] if mode == "rgbd" else mode.split("+")
        expected_names = {name for part in parts for name in expected[part]}
        assert extra == expected_names | (set() if mode == "pointcloud" else set(params)), mode
        # a trained policy's inputs name the mode that provides them
        assert obs_mode_for(features) == ("rgbd" if mode == "rgb+depth" else mode)
    features = observation_features(env, "rgb+depth+segmentation")
    depth = features["observation.images.hand_camera_depth"]
    assert depth["dtype"] == "video" and depth["shape"] == (128, 128, 1) and depth["info"]["is_depth_map"]
    seg = features["observation.images.base_camera_segmentation"]
    assert seg["dtype"] == "image" and seg["shape"] == (128, 128, 1)
    assert (
        seg["info"]["segmentation_ids"]["0"] == "background"
        and "obj_to_place" in seg["info"]["segmentation_ids"].values()
    )
    cloud = observation_features(env, "pointcloud", points=POINTS)
    assert cloud["observation.pointcloud.xyz"]["shape"] == (POINTS, 3)
    assert cloud["observation.pointcloud.xyz"]["info"] == {"unit": "m", "frame": "world"}
    env.close()


def _replay(root: Path, task: str, mode: str):
    """The recorded episode re-simulated from its seed with its executed actions, in the recording's obs mode:
    (env, per-frame observations)."""
    from tests.test_recording import _columns

    settings = json.loads((root / "meta/kitbench_recording.json").read_text())
    columns = _columns(root)
    env = gym.make(f"kitbench/{task}", obs_mode=mode, control_mode=settings["control_mode"])
    obs, _ = env.reset(seed=settings["seed"])
    observations = [obs]
    for action in columns["executed_action"][:-1]:
        obs, *_ = env.step(action)
        observations.append(obs)
    return env, observations


@pytest.mark.parametrize(("task", "mode"), RECORDINGS, ids=[f"{t}-{m}" for t, m in RECORDINGS])
def test_stock_lerobot_loads_each_modality_as_the_env_gave_it(recordings, needs_vulkan, task, mode):
    """Depth within half a 2 mm code, segmentation ids and point clouds exactly; in the layout and units stock
    `LeRobotDataset` returns (depth in its default millimetres, and in metres when asked), which is also what trained
    policies and the LeRobot plugin are fed (`as_loaded`)."""
    root = recordings[task, mode]
    ds = _load(root)
    in_metres = _load(root, depth_output_unit="m")
    env, observations = _replay(root, task, mode)
    assert len(observations) == len(ds)
    info = json.loads((root / "meta/info.json").read_text())["features"]
    sampler = PointSampler(POINTS, 3)
    checked = {"depth": 0, "segmentation": 0, "pointcloud": 0, "sensor_param": 0}
    for i, obs in enumerate(observations):
        frame = observation_frame(env, obs, sampler)
        if i % 7:  # every 7th frame is compared: decoding each is the slow part (the sampler still draws each)
            continue
        item = ds[i]
        expected = as_loaded(
            {k: v for k, v in frame.items() if k.split(".")[1] in ("images", "pointcloud", "sensor_param")}
        )
        for name, value in expected.items():
            got = item[name].numpy()
            assert got.shape == value.shape, name
            if name.endswith("_depth"):
                assert info[name]["info"]["depth_unit"] == "m"  # what the frames were given in
                assert np.abs(got - value).max() <= 1000 * DEPTH_STEP / 2 + 1e-3, name  # millimetres
                metres = in_metres[i][name].numpy()
                assert np.abs(metres - frame[name].transpose(2, 0, 1)).max() <= DEPTH_STEP / 2 + 1e-6
                assert (got[value == 0] == 0).all()  # pixels that see nothing stay 0
                checked["depth"] += 1
            elif name.endswith("_segmentation"):
                np.testing.assert_array_equal(got, value, err_msg=name)
                checked["segmentation"] += 1
            elif name.startswith("observation.pointcloud."):
                np.testing.assert_array_equal(got, value, err_msg=name)
                checked["pointcloud"] += 1
            elif name.startswith("observation.sensor_param."):
                np.testing.assert_array_equal(got, value, err_msg=name)
                checked["sensor_param"] += 1
    env.close()
    if mode == "pointcloud":
        assert checked["pointcloud"] > 0
    else:
        assert checked["depth"] > 0 and checked["segmentation"] > 0 and checked["sensor_param"] > 0


@pytest.mark.parametrize(("task", "mode"), RECORDINGS, ids=[f"{t}-{m}" for t, m in RECORDINGS])
def test_mcap_logs_depth_segmentation_and_the_cloud(recordings, needs_vulkan, task, mode):
    from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
    from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
    from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
    from mcap.reader import make_reader

    root = recordings[task, mode]
    env, observations = _replay(root, task, mode)
    with open(root / "mcap" / "episode_000000.mcap", "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        schemas = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
        raw: dict[str, list[bytes]] = {}
        for _, channel, message in reader.iter_messages():
            raw.setdefault(channel.topic, []).append(message.data)
    kinds = {
        "foxglove.PointCloud": PointCloud,
        "foxglove.RawImage": RawImage,
        "foxglove.CompressedImage": CompressedImage,
    }
    messages = {
        t: [(d, kinds[schemas[t]].FromString(d) if schemas[t] in kinds else None) for d in v] for t, v in raw.items()
    }
    cameras = env.unwrapped.camera_names
    if mode == "pointcloud":
        assert schemas["/pointcloud"] == "foxglove.PointCloud"
        assert not any(
            t.endswith(("/depth", "/segmentation")) or t in {f"/camera/{c}" for c in cameras} for t in schemas
        )
        cloud = observations[4]["pointcloud"]
        msg = messages["/pointcloud"][4][1]
        assert msg.frame_id == "world"
        names = [f.name for f in msg.fields]
        assert names[:3] == ["x", "y", "z"] and {"red", "green", "blue", "alpha", "segmentation"} <= set(names)
        kept = cloud["xyzw"][:, 3] > 0
        assert len(msg.data) == msg.point_stride * int(kept.sum())
        xyz = np.frombuffer(msg.data, dtype=np.float32).reshape(-1, msg.point_stride // 4)[:, :3]
        np.testing.assert_array_equal(xyz, cloud["xyzw"][kept, :3])
    else:
        ids = json.loads(messages["/segmentation_ids"][0][0])
        assert ids == {str(k): v for k, v in env.unwrapped.segmentation_id_map.items()}
        for camera in cameras:
            assert schemas[f"/camera/{camera}/depth"] == "foxglove.RawImage"
            assert schemas[f"/camera/{camera}/segmentation"] == "foxglove.CompressedImage"
            depth = messages[f"/camera/{camera}/depth"][4][1]
            assert depth.encoding == "32FC1" and depth.frame_id == camera and depth.step == 4 * depth.width
            image = np.frombuffer(depth.data, dtype="<f4").reshape(depth.height, depth.width)
            np.testing.assert_array_equal(image, observations[4]["sensor_data"][camera]["depth"][..., 0])
            seg = messages[f"/camera/{camera}/segmentation"][4][1]
            assert seg.format == "png"
            # one colour per id: as many colours in the picture as ids in the segmentation
            from io import BytesIO

            from PIL import Image

            colours = np.asarray(Image.open(BytesIO(seg.data))).reshape(-1, 3)
            labels = observations[4]["sensor_data"][camera]["segmentation"].reshape(-1)
            assert len(np.unique(colours, axis=0)) == len(np.unique(labels))
    env.close()


@pytest.mark.parametrize(("task", "mode"), RECORDINGS, ids=[f"{t}-{m}" for t, m in RECORDINGS])
def test_every_modality_trains_a_few_steps_with_lerobot_train(recordings, needs_vulkan, task, mode, tmp_path):
    root = recordings[task, mode]
    info = json.loads((root / "meta/info.json").read_text())["features"]
    rgb = [n for n in info if n.startswith("observation.images.") and info[n]["shape"][-1] == 3]
    inputs = ["observation.state", "observation.environment_state", *rgb]
    out = tmp_path / "train"
    lerobot_train(small_config(root, tmp_path, inputs), root, out, tmp_path)
    saved = json.loads((out / "checkpoints" / "last" / "pretrained_model" / "config.json").read_text())
    assert set(saved["input_features"]) == set(inputs)

    # What `kitbench eval` feeds a policy that reads every stored feature: the dataset's values, by name.
    from lerobot.configs import FeatureType, PolicyFeature

    from kitbench.policies.lerobot_policy import LeRobotPolicy

    policy = LeRobotPolicy(str(out))
    for name, feature in info.items():
        if name.startswith("observation."):
            shape = feature["shape"]
            shape = (shape[2], shape[0], shape[1]) if feature["dtype"] in ("video", "image") else tuple(shape)
            policy.config.input_features[name] = PolicyFeature(type=FeatureType.STATE, shape=shape)
    needed = policy.requirements()["obs_mode"]
    assert needed == ("rgbd" if mode == "rgb+depth" else mode)
    settings = json.loads((root / "meta/kitbench_recording.json").read_text())
    env = gym.make(f"kitbench/{task}", obs_mode=mode, control_mode=settings["control_mode"])
    obs, info = env.reset(seed=settings["seed"])
    policy.reset(env, settings["seed"], obs, info)
    batch = policy._batch(obs)
    item = _load(root)[0]
    for name in info:
        if not name.startswith("observation."):
            continue
        got, stored = batch[name].numpy(), item[name].numpy()
        assert got.shape == stored.shape, name
        if name.endswith("_depth"):
            assert np.abs(got - stored).max() <= 1000 * DEPTH_STEP / 2 + 1e-3, name  # millimetres
        elif name.startswith("observation.images.") and not name.endswith("_segmentation"):
            assert np.abs(got - stored).mean() < 0.02, name  # rgb, through a lossy video codec
        else:
            np.testing.assert_allclose(got, stored, rtol=1e-6, atol=1e-6, err_msg=name)
    env.close()


def test_lerobot_doctor_finds_no_failure_in_depth_that_a_camera_recording_lacks(recordings, needs_vulkan):
    def failures(root: Path) -> set[str]:
        run = subprocess.run(
            [str(BIN / "lerobot-doctor"), "check", str(root), "--json"],
            capture_output=True,
            text=True,
            env=OFFLINE,
            timeout=300,
        )
        assert run.stdout.strip(), run.stderr[-2000:]
        checks = json.loads(run.stdout[run.stdout.index("{") :])["checks"]
        assert len(checks) >= 5, checks  # it ran its checks
        return {c["name"] for c in checks if c["severity"] not in ("PASS", "WARN", "INFO")}

    camera = failures(recordings["LiftPegUpright-v1", "rgb"])
    depth = failures(recordings["LiftPegUpright-v1", TEXTURES])
    assert depth <= camera, depth - camera


@pytest.mark.parametrize(
    ("kwargs", "needle"),
    [
        ({"obs_mode": "state_dict"}, "unknown obs_mode 'state_dict'; valid choices: state, rgb, rgbd, "),
        ({"obs_mode": "pointclouds"}, "valid choices: state, rgb, rgbd, depth, segmentation, rgb+depth"),
        ({"obs_mode": "pointcloud", "pointcloud_points": 0}, "pointcloud_points must be a positive integer, got 0"),
    ],
)
def test_a_mode_a_dataset_cannot_hold_is_refused_before_anything_is_written(tmp_path, kwargs, needle):
    out = tmp_path / "never"
    config = RecordConfig.of(task="LiftPegUpright-v1", episodes=1, out=out, **kwargs)
    with pytest.raises(KitbenchError) as error:
        record(config, progress=False)
    assert needle in str(error.value) and "\n" not in str(error.value)
    assert not out.exists()


@pytest.mark.parametrize("obs_type", ["rgb+depth+segmentation", "pointcloud"])
def test_the_lerobot_plugin_gives_each_modality_under_the_dataset_names(needs_vulkan, obs_type):
    """`--env.type=kitbench --env.obs_type=<mode>`: every feature a dataset of that mode stores reaches lerobot's
    observation under its dataset name (rgb through `pixels`, the rest as `LeRobotDataset` returns it)."""
    from lerobot.envs.utils import preprocess_observation

    import lerobot_env_kitbench  # noqa: F401
    from lerobot_env_kitbench.config import KitbenchEnvConfig

    config = KitbenchEnvConfig(task="AssemblingKits-v1", obs_type=obs_type, pointcloud_points=POINTS)
    env = gym.make("gym_kitbench/AssemblingKits-v1", **{**config.gym_kwargs, "render_mode": None})
    obs, _ = env.reset(seed=5)
    batch = preprocess_observation(dict(obs.items()))
    assert set(batch) == set(config.features_map.values()) - {"action"}
    reference = gym.make("kitbench/AssemblingKits-v1", obs_mode=obs_type)
    frame = as_loaded(observation_frame(reference, reference.reset(seed=5)[0], PointSampler(POINTS, 5)))
    for name, value in frame.items():
        np.testing.assert_allclose(batch[name].numpy().reshape(value.shape), value, rtol=1e-6, err_msg=name)
    env.close()
    reference.close()


def test_kitbench_package_lists_every_modality():
    assert {"depth", "segmentation", "pointcloud", "rgbd"} <= set(kitbench.envs.modes.OBS_MODES)
