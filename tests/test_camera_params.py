"""The cameras' parameters in camera datasets (`observation.sensor_param.<camera>.*`): stored every frame with
ManiSkill's names and conventions, enough to lift a stored depth frame to world points from stock `LeRobotDataset`
alone (`depth_to_world`, the snippet of docs/observations.md); absent from state recordings; fed to a policy whose
inputs name them, by `kitbench eval` and the LeRobot plugin."""

from __future__ import annotations

import inspect
import json
import os
import re
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import kitbench  # noqa: F401
from kitbench.envs import features as env_features_module
from kitbench.envs.features import CAMERA_PARAMS, SENSOR_PARAM, obs_mode_for, observation_features
from kitbench.envs.modes import IMAGE_OBS_MODES
from kitbench.errors import KitbenchError
from kitbench.recording.convert import convert_config
from kitbench.recording.recorder import RecordConfig, record

os.environ.setdefault("HF_HUB_OFFLINE", "1")

ROOT = Path(__file__).resolve().parents[1]
TASKS = ("AssemblingKits-v1", "LiftPegUpright-v1")
# The table top is the plane z = 0 (`sim.scene.add_table_and_ground`). A stored depth is within 1 mm of the rendered
# one (a 2 mm code); measured: table pixels lift to within 1.3 mm of the plane from every camera of both tasks. Pixel
# centres taken at integer coordinates (OpenCV's habit; SAPIEN's intrinsics put them at + 0.5) land 3.4 mm
# (AssemblingKits' base camera) and 6.1 mm (LiftPegUpright's) off it.
TABLE_TOLERANCE = 0.003
# Two cameras' least-squares planes through their own table pixels, frame by frame (measured on AssemblingKits, seed
# 2: heights within 1.03 mm, normals within 0.64 degrees, where the hand camera sees least of the table, 942 pixels);
# a camera placed by a wrong convention is centimetres and degrees off.
PLANE_HEIGHT_TOLERANCE = 0.002
# The hand camera's table patch whose plane's tilt is compared (at seed 2's last frame it sees 726 pixels, near the
# board, and that patch's fit leans 2.4 degrees on 1 mm depth steps while its height stays within the tolerance).
MIN_PATCH_PIXELS = 900
PLANE_ANGLE_TOLERANCE = 1.5


def depth_to_world(depth_mm: np.ndarray, intrinsic_cv: np.ndarray, cam2world_gl: np.ndarray) -> np.ndarray:
    """(H, W) depth in millimetres along the viewing axis -> (H, W, 3) world points in metres. The matrices as
    stored (flat, row by row) or reshaped."""
    k, pose = np.reshape(intrinsic_cv, (3, 3)), np.reshape(cam2world_gl, (4, 4))
    height, width = depth_mm.shape
    z = depth_mm.astype(np.float64) / 1000.0
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)  # pixel centres
    x, y = (u - k[0, 2]) / k[0, 0] * z, (v - k[1, 2]) / k[1, 1] * z  # OpenCV camera axes: x right, y down, z forward
    gl = np.stack([x, -y, -z, np.ones_like(z)], axis=-1)  # OpenGL camera axes: x right, y up, z backward
    return (gl @ pose.T)[..., :3]


def _via_extrinsic(depth_mm: np.ndarray, intrinsic_cv: np.ndarray, extrinsic_cv: np.ndarray) -> np.ndarray:
    """The same points from `extrinsic_cv` (world to OpenCV camera, [R | t]): world = R^T (camera - t)."""
    k, extrinsic = intrinsic_cv.reshape(3, 3).astype(np.float64), extrinsic_cv.reshape(3, 4).astype(np.float64)
    height, width = depth_mm.shape
    z = depth_mm.astype(np.float64) / 1000.0
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    camera = np.stack([u * z, v * z, z], axis=-1) @ np.linalg.inv(k).T
    return (camera - extrinsic[:, 3]) @ extrinsic[:, :3]


def _load(root: Path):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    return LeRobotDataset("kitbench/test", root=root)


def _cameras(features: dict) -> list[str]:
    return sorted({name[len(SENSOR_PARAM) :].rsplit(".", 1)[0] for name in features if name.startswith(SENSOR_PARAM)})


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    """One expert episode of each task with depth and segmentation (the table's pixels picked by their label)."""
    base = tmp_path_factory.mktemp("camera_params")
    out = {}
    for task in TASKS:
        out[task] = base / task
        config = RecordConfig.of(
            task, 1, out[task], seed=2, obs_mode="depth+segmentation", control_mode="pd_joint_pos", mcap=False
        )
        record(config, progress=False)
    return out


@pytest.fixture(scope="module")
def frames(recordings):
    """Per task and camera, every frame as stock `LeRobotDataset` returns it: depth (mm), the table's pixels and the
    three parameters, as numpy."""
    out = {}
    for task, root in recordings.items():
        ds = _load(root)
        features = ds.meta.features
        for camera in _cameras(features):
            ids = features[f"observation.images.{camera}_segmentation"]["info"]["segmentation_ids"]
            table = int(next(i for i, name in ids.items() if name == "table"))
            rows = []
            for i in range(len(ds)):
                item = ds[i]
                row = {name: item[f"{SENSOR_PARAM}{camera}.{name}"].numpy() for name in CAMERA_PARAMS}
                row["depth"] = item[f"observation.images.{camera}_depth"][0].numpy()
                row["table"] = (item[f"observation.images.{camera}_segmentation"][0].numpy() == table) & (
                    row["depth"] > 0
                )
                rows.append(row)
            out[task, camera] = rows
    return out


def test_the_snippet_in_the_docs_is_the_tested_function():
    text = (ROOT / "docs/observations.md").read_text()
    match = re.search(r"^def depth_to_world\(.*?(?=\n\n)", text, re.S | re.M)
    assert match, "docs/observations.md has no depth_to_world"
    assert match.group(0).strip() == inspect.getsource(depth_to_world).strip()


def test_every_camera_dataset_declares_each_cameras_parameters_and_state_none():
    env = gym.make("kitbench/AssemblingKits-v1", obs_mode="state")
    for mode in IMAGE_OBS_MODES:
        features = observation_features(env, mode)
        params = {name: f for name, f in features.items() if name.startswith(SENSOR_PARAM)}
        if mode == "pointcloud":  # world-frame points, no camera to apply them to
            assert not params
            continue
        assert _cameras(features) == ["base_camera", "hand_camera"], mode
        for camera in _cameras(features):
            # named as the camera's images are
            assert any(name.startswith(f"observation.images.{camera}") for name in features), (mode, camera)
            for name, shape in (("intrinsic_cv", (3, 3)), ("extrinsic_cv", (3, 4)), ("cam2world_gl", (4, 4))):
                feature = params[f"{SENSOR_PARAM}{camera}.{name}"]
                # a matrix stored row by row: LeRobot's tools edit and merge 1-D features only
                assert feature["dtype"] == "float32" and tuple(feature["shape"]) == (shape[0] * shape[1],)
                assert feature["info"]["matrix"] == list(shape) and feature["names"][shape[1]] == "r1c0"
    for mode in ("state", "state_dict"):
        assert not any(n.startswith(SENSOR_PARAM) for n in observation_features(env, mode))
    # a policy that reads the parameters without an image needs a camera mode all the same
    assert obs_mode_for(["observation.state", f"{SENSOR_PARAM}hand_camera.extrinsic_cv"]) == "rgb"
    env.close()


@pytest.mark.parametrize("task", TASKS)
def test_table_pixels_lift_onto_the_table_plane_from_every_camera_at_every_frame(frames, needs_vulkan, task):
    cameras = [camera for (t, camera) in frames if t == task]
    assert cameras == (["base_camera", "hand_camera"] if task == "AssemblingKits-v1" else ["base_camera"])
    for camera in cameras:
        for i, row in enumerate(frames[task, camera]):
            assert row["table"].sum() > 200, (camera, i)  # every camera sees the table in every frame
            points = depth_to_world(row["depth"], row["intrinsic_cv"], row["cam2world_gl"])[row["table"]]
            assert np.abs(points[:, 2]).max() <= TABLE_TOLERANCE, (camera, i)
            # extrinsic_cv is the inverse of cam2world_gl, in OpenCV axes: the same points
            same = _via_extrinsic(row["depth"], row["intrinsic_cv"], row["extrinsic_cv"])[row["table"]]
            np.testing.assert_allclose(same, points, atol=1e-5, err_msg=f"{camera} frame {i}")


def _plane(points: np.ndarray, at: np.ndarray) -> tuple[np.ndarray, float]:
    """The least-squares plane z = a x + b y + c through `points`: its unit normal and its height at `at` (x, y)."""
    (a, b, c), *_ = np.linalg.lstsq(np.c_[points[:, :2], np.ones(len(points))], points[:, 2], rcond=None)
    normal = np.array([-a, -b, 1.0])
    return normal / np.linalg.norm(normal), float(a * at[0] + b * at[1] + c)


def test_the_base_and_hand_cameras_agree_on_the_table_plane(frames, needs_vulkan):
    """Compared where the hand camera sees the table: a small patch's plane, carried to a point far from it, turns
    a fraction of a degree of fit into millimetres."""
    base, hand = frames["AssemblingKits-v1", "base_camera"], frames["AssemblingKits-v1", "hand_camera"]
    for i, (b, h) in enumerate(zip(base, hand, strict=True)):
        points = [
            depth_to_world(row["depth"], row["intrinsic_cv"], row["cam2world_gl"])[row["table"]] for row in (b, h)
        ]
        at = points[1][:, :2].mean(axis=0)
        (normal_b, height_b), (normal_h, height_h) = (_plane(p, at) for p in points)
        assert abs(height_b - height_h) <= PLANE_HEIGHT_TOLERANCE, i
        if len(points[1]) >= MIN_PATCH_PIXELS:  # a patch smaller than that tilts with the depth's 1 mm steps
            assert np.degrees(np.arccos(min(1.0, float(normal_b @ normal_h)))) <= PLANE_ANGLE_TOLERANCE, i


def test_the_hand_camera_moves_with_the_arm_and_the_base_camera_stays(frames, recordings, needs_vulkan):
    for (task, camera), rows in frames.items():
        extrinsics = np.stack([row["extrinsic_cv"] for row in rows])
        intrinsics = np.stack([row["intrinsic_cv"] for row in rows])
        assert (intrinsics == intrinsics[0]).all(), (task, camera)
        moved = (extrinsics[1:] != extrinsics[:-1]).any(axis=1)
        if camera == "hand_camera":
            assert moved.mean() > 0.5, moved  # every step of the expert's moves the arm (measured: all)
        else:
            assert not moved.any(), (task, camera)
        # frame 0 holds what the env reports at the episode's reset
        settings = json.loads((recordings[task] / "meta/kitbench_recording.json").read_text())
        env = gym.make(f"kitbench/{task}", obs_mode="depth", control_mode=settings["control_mode"])
        obs, _ = env.reset(seed=settings["seed"])
        for name, param in CAMERA_PARAMS.items():
            stored = rows[0][name].reshape(param.shape)
            np.testing.assert_array_equal(stored, obs["sensor_param"][camera][name], err_msg=name)
        env.close()


def test_the_card_lists_the_parameters_and_their_conventions(recordings):
    card = (recordings["AssemblingKits-v1"] / "README.md").read_text()
    for camera in ("base_camera", "hand_camera"):
        for name, param in CAMERA_PARAMS.items():
            size = (param.shape[0] * param.shape[1],)
            assert f"| `{SENSOR_PARAM}{camera}.{name}` | float32 | {size} | {param.description} |" in card
    assert "OpenCV camera axes: x right, y down, z forward" in card and "x right, y up, z backward" in card
    assert "world to camera [R | t]" in card and "returned by stock `LeRobotDataset` in millimetres" in card
    assert "`.reshape(3, 3)`" in card
    info = json.loads((recordings["AssemblingKits-v1"] / "meta/info.json").read_text())["features"]
    assert info[f"{SENSOR_PARAM}hand_camera.extrinsic_cv"]["info"] == {
        "unit": "m",
        "transform": "world to camera",
        "axes": "opencv",
        "matrix": [3, 4],
    }


def test_a_state_recording_has_no_camera_parameters(tmp_path):
    out = tmp_path / "state"
    record(RecordConfig.of("LiftPegUpright-v1", 1, out, mcap=False), progress=False)
    info = json.loads((out / "meta/info.json").read_text())["features"]
    assert not [name for name in info if "sensor_param" in name]
    assert "Cameras:" not in (out / "README.md").read_text()


def test_a_recording_made_before_camera_parameters_loads_converts_and_resumes(tmp_path, needs_vulkan, monkeypatch):
    old = tmp_path / "old"
    with monkeypatch.context() as before:  # the features of a camera dataset before cameras' parameters were stored
        before.setattr(env_features_module, "CAMERA_PARAMS", {})
        record(RecordConfig.of("LiftPegUpright-v1", 1, old, obs_mode="rgb", mcap=False), progress=False)
    ds = _load(old)
    assert "observation.images.base_camera" in ds.meta.features
    assert not [name for name in ds.meta.features if name.startswith(SENSOR_PARAM)]
    assert tuple(ds[0]["observation.images.base_camera"].shape) == (3, 128, 128)
    # converted, it gains them
    new = tmp_path / "new"
    summary = record(convert_config(old, new, obs_mode="depth"), progress=False)
    assert summary.stored == 1 and summary.rejected == 0
    converted = _load(new)
    assert tuple(converted[0][f"{SENSOR_PARAM}base_camera.cam2world_gl"].shape) == (16,)
    # resumed, it goes on with the features it was started with
    record(RecordConfig.of("LiftPegUpright-v1", 2, old, obs_mode="rgb", mcap=False, resume=True), progress=False)
    resumed = _load(old)
    assert resumed.num_episodes == 2
    assert not [name for name in resumed.meta.features if name.startswith(SENSOR_PARAM)]
    assert tuple(resumed[len(resumed) - 1]["observation.images.base_camera"].shape) == (3, 128, 128)


def test_eval_save_dataset_keeps_them_too(tmp_path, needs_vulkan):
    from kitbench.evaluation.config import EvalConfig
    from kitbench.evaluation.runner import run_eval
    from kitbench.evaluation.suite import adhoc_suite

    suite = adhoc_suite("LiftPegUpright-v1", 1, 7, obs_mode="rgb", control_mode="pd_joint_pos")
    data = tmp_path / "scored"
    run_eval(EvalConfig.of(suite, "expert", tmp_path / "report", save_dataset=data), progress=False)
    item = _load(data)[0]
    env = gym.make("kitbench/LiftPegUpright-v1", obs_mode="rgb", control_mode="pd_joint_pos")
    expected = env.reset(seed=7)[0]["sensor_param"]["base_camera"]
    for name, param in CAMERA_PARAMS.items():
        stored = item[f"{SENSOR_PARAM}base_camera.{name}"].numpy().reshape(param.shape)
        np.testing.assert_array_equal(stored, expected[name], err_msg=name)
    env.close()


def _checkpoint(path: Path, env, inputs: list[str]) -> Path:
    """An untrained small ACT whose inputs are `inputs` (shapes as the env provides them), saved as lerobot-train
    saves one: what `kitbench eval --policy lerobot:<path>` loads."""
    from lerobot.configs import FeatureType, PolicyFeature
    from lerobot.policies import make_pre_post_processors
    from lerobot.policies.act.configuration_act import ACTConfig
    from lerobot.policies.act.modeling_act import ACTPolicy

    from kitbench.policies.lerobot_policy import env_features

    provided = env_features(env)
    features = {
        name: PolicyFeature(
            type=FeatureType.VISUAL if len(provided[name]) == 3 else FeatureType.STATE, shape=provided[name]
        )
        for name in inputs
    }
    action = PolicyFeature(type=FeatureType.ACTION, shape=env.action_space.shape)
    sizes = {"chunk_size": 2, "n_action_steps": 2, "dim_model": 16, "dim_feedforward": 32, "n_heads": 2}
    config = ACTConfig(
        input_features=features,
        output_features={"action": action},
        device="cpu",
        pretrained_backbone_weights=None,
        n_encoder_layers=1,
        n_decoder_layers=1,
        **sizes,
    )
    ACTPolicy(config).save_pretrained(path)
    for processor in make_pre_post_processors(config):
        processor.save_pretrained(path)
    return path


def test_a_policy_that_names_camera_parameters_is_fed_them(tmp_path, needs_vulkan):
    from kitbench.policies.lerobot_policy import LeRobotPolicy

    env = gym.make("kitbench/LiftPegUpright-v1", obs_mode="rgb")
    extrinsic, pose = f"{SENSOR_PARAM}base_camera.extrinsic_cv", f"{SENSOR_PARAM}base_camera.cam2world_gl"
    inputs = ["observation.state", "observation.images.base_camera", extrinsic, pose]
    policy = LeRobotPolicy(str(_checkpoint(tmp_path / "act", env, inputs)))
    assert policy.requirements() == {"obs_mode": "rgb", "camera_size": "128x128"}  # the size it was trained at
    obs, info = env.reset(seed=4)
    policy.reset(env, 4, obs, info)
    batch = policy._batch(obs)
    for name, key in ((extrinsic, "extrinsic_cv"), (pose, "cam2world_gl")):
        np.testing.assert_array_equal(batch[name].numpy(), obs["sensor_param"]["base_camera"][key].reshape(-1))
    assert f"{SENSOR_PARAM}base_camera.intrinsic_cv" not in batch  # only what the policy reads
    assert policy.act(obs).shape == env.action_space.shape
    env.close()
    state = gym.make("kitbench/LiftPegUpright-v1", obs_mode="state")
    with pytest.raises(KitbenchError, match=re.escape(f"mismatched: observation.images.base_camera, {extrinsic}")):
        policy.check(state)
    state.close()


def test_the_lerobot_plugin_gives_the_parameters_under_the_dataset_names(needs_vulkan):
    from lerobot.configs import FeatureType
    from lerobot.envs.utils import preprocess_observation

    import lerobot_env_kitbench  # noqa: F401
    from lerobot_env_kitbench.config import KitbenchEnvConfig

    config = KitbenchEnvConfig(task="AssemblingKits-v1", obs_type="pixels_state")
    key = "sensor_param.hand_camera.cam2world_gl"
    assert config.features_map[key] == f"observation.{key}"
    assert config.features[key].type is FeatureType.STATE and tuple(config.features[key].shape) == (16,)
    assert not [k for k in KitbenchEnvConfig(task="AssemblingKits-v1").features if k.startswith("sensor_param.")]
    env = gym.make("gym_kitbench/AssemblingKits-v1", **{**config.gym_kwargs, "render_mode": None})
    obs, _ = env.reset(seed=5)
    batch = preprocess_observation(dict(obs.items()))
    reference = gym.make("kitbench/AssemblingKits-v1", obs_mode="rgb")
    expected = reference.reset(seed=5)[0]["sensor_param"]
    for camera in ("base_camera", "hand_camera"):
        for name in CAMERA_PARAMS:
            got = batch[f"{SENSOR_PARAM}{camera}.{name}"].numpy().reshape(expected[camera][name].shape)
            np.testing.assert_array_equal(got, expected[camera][name], err_msg=f"{camera} {name}")
    env.close()
    reference.close()
