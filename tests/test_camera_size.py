"""A recipe's camera size (`camera_size`, ManiSkill's `sensor_configs` in the env) reaches every place an image does:
the env's observations and camera parameters, the dataset's features and frames, the MCAP log's images and
calibrations, the recording's settings (so a resume at another size is refused), and the env that scores a
policy trained on it; a policy is never scored on images of another size."""

from __future__ import annotations

import io
from types import SimpleNamespace

import gymnasium as gym
import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

import kitbench  # noqa: F401
from kitbench.env_settings import canonical_size
from kitbench.errors import KitbenchError
from kitbench.evaluation.runner import fit_suite_to_policy
from kitbench.evaluation.suite import Suite
from kitbench.metadata import RecordingInfo, lerobot_info
from kitbench.recording.recorder import RecordConfig, record

TASK = "LiftPegUpright-v1"


def test_the_env_renders_at_the_size_asked_with_the_same_field_of_view(needs_vulkan):
    env = gym.make(f"kitbench/{TASK}", obs_mode="rgb", sensor_configs={"width": 96, "height": 64})
    obs, _ = env.reset(seed=0)
    assert obs["sensor_data"]["base_camera"]["rgb"].shape == (64, 96, 3)
    k = obs["sensor_param"]["base_camera"]["intrinsic_cv"]
    default = gym.make(f"kitbench/{TASK}", obs_mode="rgb")
    k128 = default.reset(seed=0)[0]["sensor_param"]["base_camera"]["intrinsic_cv"]
    np.testing.assert_allclose(k[1, 1], k128[1, 1] * 64 / 128)  # focal length scales with the height: same fov
    np.testing.assert_allclose(k[:2, 2], [48, 32])
    env.close()
    default.close()


@pytest.mark.parametrize(
    ("configs", "message"),
    [
        ({"width": 4}, "8 to 4096"),
        ({"width": 64.0}, "whole number"),
        ({"base_kamera": {"width": 64}}, "valid keys: width, height, base_camera"),
        ({"base_camera": {"depth": 1}}, "may set only width, height, fov, pose"),
    ],
)
def test_bad_sensor_configs_are_one_line(configs, message):
    with pytest.raises(KitbenchError, match=message):
        gym.make(f"kitbench/{TASK}", obs_mode="rgb", sensor_configs=configs)


@pytest.mark.parametrize("value", ["64x", "0", "x64", "big", "64x64x3", "5000"])
def test_a_bad_camera_size_setting_is_one_line(value, tmp_path):
    with pytest.raises(KitbenchError, match="camera_size must be WIDTHxHEIGHT"):
        RecordConfig.of(task=TASK, episodes=1, out=tmp_path / "x", obs_mode="rgb", camera_size=value)


def test_sizes_compare_however_they_are_spelled():
    assert canonical_size(64) == canonical_size("64") == canonical_size("64X64") == "64x64"
    assert canonical_size("128x128") is None and canonical_size(None) is None  # the cameras' own size
    assert canonical_size("96x64") == "96x64"


def test_a_recipes_camera_size_reaches_the_dataset_the_mcap_log_and_the_settings(needs_vulkan, tmp_path):
    out = tmp_path / "ds"
    record(RecordConfig.of(task=TASK, episodes=1, out=out, obs_mode="rgb", camera_size="64x48"), progress=False)
    features = lerobot_info(out)["features"]
    assert features["observation.images.base_camera"]["shape"] == [48, 64, 3]
    assert RecordingInfo.read(out).camera_size == "64x48"
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    frame = LeRobotDataset("kitbench/test", root=out)[0]["observation.images.base_camera"]
    assert tuple(frame.shape) == (3, 48, 64)
    data = next((out / "mcap").glob("*.mcap")).read_bytes()
    reader = make_reader(io.BytesIO(data), decoder_factories=[DecoderFactory()])
    calibrations = images = 0
    cameras = ["/camera/base_camera", "/camera/base_camera/calibration"]
    for _, channel, _, message in reader.iter_decoded_messages(topics=cameras):
        if channel.topic == "/camera/base_camera/calibration":
            assert (message.width, message.height) == (64, 48)
            assert message.K[2] == 32 and message.K[5] == 24  # the principal point of a 64x48 image
            calibrations += 1
        elif channel.topic == "/camera/base_camera":
            from PIL import Image

            assert Image.open(io.BytesIO(message.data)).size == (64, 48)
            images += 1
    assert calibrations == 1 and images > 1
    # a resume at another size is another recording
    with pytest.raises(KitbenchError, match="camera_size: recorded '64x48', asked None"):
        record(RecordConfig.of(task=TASK, episodes=2, out=out, obs_mode="rgb", resume=True), progress=False)


def _policy(size: str | None):
    """What `fit_suite_to_policy` reads of a policy: its name and requirements."""
    needs = {"obs_mode": "rgb", **({"camera_size": size} if size else {})}
    return SimpleNamespace(name="lerobot:trained", requirements=lambda: needs)


def test_the_env_that_scores_a_policy_renders_at_the_size_it_was_trained_at():
    suite = Suite(task=TASK, seeds=(0,))
    assert fit_suite_to_policy(suite, _policy("64x64"), {}).camera_size == "64x64"
    assert fit_suite_to_policy(suite, _policy("128x128"), {}).camera_size is None
    assert fit_suite_to_policy(Suite(task=TASK, seeds=(0,), camera_size="64"), _policy("64x64"), {}).camera_size == (
        "64x64"
    )


def test_a_policy_is_never_scored_on_images_of_another_size():
    with pytest.raises(KitbenchError) as caught:
        fit_suite_to_policy(Suite(task=TASK, seeds=(0,), camera_size="96x96"), _policy("64x64"), {})
    message = str(caught.value)
    assert "\n" not in message and "trained on 64x64" in message and "--camera-size 64x64" in message
    with pytest.raises(KitbenchError, match="trained on 128x128"):
        fit_suite_to_policy(Suite(task=TASK, seeds=(0,), camera_size="64x64"), _policy("128x128"), {})


def test_a_lerobot_policy_requires_the_size_of_its_image_features():
    from lerobot.configs import FeatureType, PolicyFeature

    from kitbench.policies.lerobot_policy import LeRobotPolicy

    policy = LeRobotPolicy.__new__(LeRobotPolicy)
    policy.control_mode = policy.robot = policy.camera_view = None
    policy.config = SimpleNamespace(
        input_features={
            "observation.state": PolicyFeature(FeatureType.STATE, (8,)),
            "observation.images.base_camera": PolicyFeature(FeatureType.VISUAL, (3, 48, 64)),
        }
    )
    assert policy.requirements()["camera_size"] == "64x48"


def test_the_lerobot_env_config_takes_the_size(tmp_path):
    from lerobot_env_kitbench.config import KitbenchEnvConfig

    config = KitbenchEnvConfig(task=TASK, obs_type="pixels_state", camera_size="64")
    assert config.features["pixels/base_camera"].shape == (64, 64, 3)
    assert config.gym_kwargs["sensor_configs"] == {"width": 64, "height": 64}
    assert "sensor_configs" not in KitbenchEnvConfig(task=TASK, obs_type="pixels_state").gym_kwargs
