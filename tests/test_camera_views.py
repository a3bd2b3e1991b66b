"""A task's named framings of its cameras (`camera_view`, ManiSkill's `sensor_configs` pose and fov in the env): the
env renders from where the view puts the camera, a recording keeps the view (a resume in another is refused, the
card's command names it), the env that scores a policy trained on it renders it too, and a policy is never scored
from cameras that stood elsewhere in training."""

from __future__ import annotations

import json
import math
from types import SimpleNamespace

import gymnasium as gym
import numpy as np
import pytest

import kitbench  # noqa: F401
from kitbench.env_settings import PolicyEnvSettings
from kitbench.errors import KitbenchError
from kitbench.evaluation.runner import fit_suite_to_policy
from kitbench.evaluation.suite import Suite
from kitbench.metadata import RecordingInfo
from kitbench.recording.recorder import RecordConfig, record
from kitbench.sim.cameras import view
from kitbench.tasks.assembling_kits import AssemblingKitsEnv

AK, LPU = "AssemblingKits-v1", "LiftPegUpright-v1"
BOARD = AssemblingKitsEnv.camera_views["board"]["base_camera"]


def test_sensor_configs_move_a_camera_and_set_its_field_of_view(needs_vulkan):
    eye, fov = [0.3, 0.1, 0.5], 0.7
    env = gym.make(f"kitbench/{LPU}", obs_mode="rgb", sensor_configs={"base_camera": view(eye, [0, 0, 0], fov)})
    params = env.reset(seed=0)[0]["sensor_param"]["base_camera"]
    np.testing.assert_allclose(params["cam2world_gl"][:3, 3], eye, atol=1e-6)
    # OpenGL's camera looks down its -z axis: here at the origin
    forward = -params["cam2world_gl"][:3, 2]
    np.testing.assert_allclose(forward, -np.array(eye) / np.linalg.norm(eye), atol=1e-6)
    assert params["intrinsic_cv"][1, 1] == pytest.approx(64 / math.tan(fov / 2), rel=1e-5)  # 128 px high
    env.close()


@pytest.mark.parametrize(
    ("configs", "message"),
    [
        ({"base_camera": {"fov": 3.5}}, "fov must be radians between 0 and pi"),
        ({"base_camera": {"fov": True}}, "fov must be radians"),
        ({"base_camera": {"pose": [0, 0, 1]}}, "pose must be x, y, z, qw, qx, qy, qz"),
        ({"base_camera": {"pose": [0, 0, 1, 2, 0, 0, 0]}}, "unit quaternion"),
        ({"base_camera": {"zoom": 2}}, "may set only width, height, fov, pose"),
    ],
)
def test_bad_camera_settings_are_one_line(configs, message):
    with pytest.raises(KitbenchError, match=message) as caught:
        gym.make(f"kitbench/{LPU}", obs_mode="rgb", sensor_configs=configs)
    assert "\n" not in str(caught.value)


def test_a_view_is_the_tasks_sensor_configs_beside_the_size():
    settings = PolicyEnvSettings(task=AK, camera_size="64", camera_view="board")
    assert settings.sensor_configs == {"width": 64, "height": 64, "base_camera": BOARD}
    assert PolicyEnvSettings(task=AK, camera_view="board").sensor_configs == {"base_camera": BOARD}
    assert PolicyEnvSettings(task=AK).sensor_configs is None


def test_a_view_frames_the_cameras_the_robot_has():
    """LiftPegUpright's `peg` moves the task's base camera for the Panda and the SO-101's own front camera for the
    SO-101 (which has no base camera); each env gets only the framings of the cameras it renders."""
    from kitbench.tasks.lift_peg_upright import LiftPegUprightEnv

    peg = LiftPegUprightEnv.camera_views["peg"]
    assert PolicyEnvSettings(task=LPU, camera_view="peg").sensor_configs == {"base_camera": peg["base_camera"]}
    assert PolicyEnvSettings(task=LPU, robot="so101", camera_view="peg").sensor_configs == {"front": peg["front"]}
    assert LiftPegUprightEnv.observation_cameras("so101") == ("front", "wrist")
    assert LiftPegUprightEnv.observation_cameras("panda") == ("base_camera",)
    with pytest.raises(KitbenchError, match="robot 'ur5' is not supported by LiftPegUpright-v1; valid choices"):
        _ = PolicyEnvSettings(task=LPU, robot="ur5", camera_view="peg").sensor_configs


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        ({"task": AK, "camera_view": "top"}, "'top' is not one of AssemblingKits-v1's; valid choices: board"),
        ({"task": LPU, "camera_view": "board"}, "'board' is not one of LiftPegUpright-v1's; valid choices: peg"),
        (
            {"task": AK, "robot": "so101", "camera_view": "board"},
            "frames none of AssemblingKits-v1's cameras with robot so101 (front, wrist)",
        ),
    ],
)
def test_a_view_the_task_or_robot_has_not_is_one_line(settings, message, tmp_path):
    with pytest.raises(KitbenchError, match=message.replace("(", r"\(").replace(")", r"\)")):
        PolicyEnvSettings(**settings).check_camera_view()
    out = tmp_path / "never"
    with pytest.raises(KitbenchError, match="camera_view"):
        record(RecordConfig.of(episodes=1, out=out, obs_mode="rgb", **settings), progress=False)
    assert not out.exists()


def test_the_board_view_puts_more_of_the_board_in_the_picture(needs_vulkan):
    """What the view is for: the board and the shape on several times the pixels of ManiSkill's framing."""

    def pixels(camera_view):
        sensors = PolicyEnvSettings(task=AK, camera_size="64", camera_view=camera_view).sensor_configs
        env = gym.make(f"kitbench/{AK}", obs_mode="segmentation", sensor_configs=sensors)
        names = env.unwrapped.segmentation_id_map
        ids = {n: [i for i, name in names.items() if name == n] for n in ("kit", "obj_to_place")}
        counts = []
        for seed in (1000000, 1000001, 1000002):
            label = env.reset(seed=seed)[0]["sensor_data"]["base_camera"]["segmentation"][..., 0]
            counts.append([int(np.isin(label, ids[n]).sum()) for n in ("kit", "obj_to_place")])
        env.close()
        return np.array(counts)

    own, board = pixels(None), pixels("board")
    assert (board > 2 * own).all(), (own, board)


@pytest.mark.parametrize(
    ("robot", "camera", "size", "gain", "swing_ends"),
    [
        # the Panda's swing ends up to 22 cm towards the arm, the peg's centre up to 1 cm above its upright height
        ("panda", "base_camera", "64", 4.0, [(-0.22, y, 0.01) for y in (-0.1, 0.1)]),
        # the SO-101's ends 8-12 cm past the spawn centre away from the arm, up to 10 cm to either side (seeds
        # 0-39); the picture's edge cuts the standing peg 11.5 cm past it in both framings, and 9.5 cm to the side
        # in this one only
        ("so101", "front", "128", 1.3, [(x, 0.0, 0.003) for x in (0.085, 0.105)]),
    ],
)
def test_the_peg_view_shows_the_whole_peg_larger_where_it_lies_and_where_it_stands(
    needs_vulkan, robot, camera, size, gain, swing_ends
):
    """What LiftPegUpright's view is for: the peg on more pixels than the camera's own framing (several times for
    the Panda's base camera, a third more for the SO-101's front camera, which frames the work closely already), and
    never cut by the picture's edge, lying at each corner of its spawn square, standing upright there and where the
    swing ends."""
    from bench.camera_view import touches_edge
    from kitbench.sim.scene import set_actor_pose
    from kitbench.tasks.lift_peg_upright import (
        LYING_QUAT,
        PEG_HALF_LENGTH,
        PEG_HALF_WIDTH,
        ROBOT_SCALE,
        SPAWN_HALF_WIDTH,
    )

    scale = ROBOT_SCALE.get(robot, 1.0)
    standing = (math.cos(math.pi / 4), 0.0, -math.sin(math.pi / 4), 0.0)  # the long (x) axis turned to world z
    half = SPAWN_HALF_WIDTH * scale
    corners = [(x, y) for x in (-half, half) for y in (-half, half)]
    lying, upright = PEG_HALF_WIDTH * scale, PEG_HALF_LENGTH * scale
    poses = [([x, y, z], q) for x, y in corners for z, q in ((lying, LYING_QUAT), (upright, standing))]
    poses += [([x, y, upright + dz], standing) for x, y, dz in swing_ends]

    def masks(camera_view):
        settings = PolicyEnvSettings(task=LPU, robot=robot, camera_size=size, camera_view=camera_view)
        env = gym.make(
            f"kitbench/{LPU}", obs_mode="segmentation", robot_uids=robot, sensor_configs=settings.sensor_configs
        )
        env.reset(seed=0)
        peg = [i for i, name in env.unwrapped.segmentation_id_map.items() if name == "peg"]
        out = []
        for position, quaternion in poses:
            set_actor_pose(env.unwrapped.peg, position, quaternion)
            obs, *_ = env.step(np.zeros(env.action_space.shape, dtype=np.float32))  # the arm held still
            out.append(np.isin(obs["sensor_data"][camera]["segmentation"][..., 0], peg))
        env.close()
        return out

    own, close = masks(None), masks("peg")
    assert sum(m.sum() for m in close) > gain * sum(m.sum() for m in own)
    for pose, mask in zip(poses, close, strict=True):
        assert mask.any() and not touches_edge(mask), pose


def test_a_recording_keeps_its_view(needs_vulkan, tmp_path):
    out = tmp_path / "ds"
    config = RecordConfig.of(task=AK, episodes=1, out=out, obs_mode="rgb", camera_size="32", camera_view="board")
    record(config.replace(mcap=False), progress=False)
    assert RecordingInfo.read(out).camera_view == "board"
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    frame = LeRobotDataset("kitbench/test", root=out)[0]
    world_to_cv = frame["observation.sensor_param.base_camera.extrinsic_cv"].numpy().reshape(3, 4)
    eye = -world_to_cv[:, :3].T @ world_to_cv[:, 3]
    np.testing.assert_allclose(eye, BOARD["pose"][:3], atol=1e-5)
    from kitbench.recording.card import card_text

    assert "--camera-view board" in card_text(out)
    with pytest.raises(KitbenchError, match="camera_view: recorded 'board', asked None"):
        record(
            RecordConfig.of(task=AK, episodes=2, out=out, obs_mode="rgb", camera_size="32", resume=True, mcap=False),
            progress=False,
        )


def _policy(view: str | None, obs_mode: str | None = "rgb"):
    """What `fit_suite_to_policy` reads of a policy: its name and requirements."""
    needs = {k: v for k, v in {"obs_mode": obs_mode, "camera_view": view}.items() if v is not None}
    return SimpleNamespace(name="lerobot:trained", requirements=lambda: needs)


def test_the_env_that_scores_a_policy_renders_the_view_it_was_trained_on():
    suite = Suite(task=AK, seeds=(0,))
    assert fit_suite_to_policy(suite, _policy("board"), {}).camera_view == "board"
    assert fit_suite_to_policy(Suite(task=AK, seeds=(0,), camera_view="board"), _policy("board"), {}).camera_view == (
        "board"
    )
    assert fit_suite_to_policy(suite, _policy(None), {}).camera_view is None
    # a policy that reads no camera is scored wherever the cameras stand
    assert fit_suite_to_policy(Suite(task=AK, seeds=(0,), camera_view="board"), _policy(None, None), {}).camera_view


def test_a_policy_is_never_scored_from_cameras_that_stood_elsewhere():
    with pytest.raises(KitbenchError) as caught:
        fit_suite_to_policy(Suite(task=AK, seeds=(0,), camera_view="board"), _policy(None), {})
    message = str(caught.value)
    assert "\n" not in message and "trained on the task's own camera views" in message
    assert message.endswith("drop --camera-view")


def test_a_lerobot_policy_requires_the_view_of_its_training_data():
    from lerobot.configs import FeatureType, PolicyFeature

    from kitbench.policies.lerobot_policy import LeRobotPolicy

    policy = LeRobotPolicy.__new__(LeRobotPolicy)
    policy.control_mode = policy.robot = None
    policy.camera_view = "board"
    features = {"observation.state": PolicyFeature(FeatureType.STATE, (8,))}
    policy.config = SimpleNamespace(input_features=features)
    assert "camera_view" not in policy.requirements()  # a state policy: no camera to place
    features["observation.images.base_camera"] = PolicyFeature(FeatureType.VISUAL, (3, 64, 64))
    assert policy.requirements()["camera_view"] == "board"


def test_the_lerobot_env_config_takes_the_view():
    from lerobot_env_kitbench.config import KitbenchEnvConfig

    config = KitbenchEnvConfig(task=AK, obs_type="pixels_state", camera_size="64", camera_view="board")
    assert config.gym_kwargs["sensor_configs"] == {"width": 64, "height": 64, "base_camera": BOARD}
    with pytest.raises(KitbenchError, match="valid choices: board"):
        KitbenchEnvConfig(task=AK, obs_type="pixels_state", camera_view="side")


def test_an_evaluations_saved_dataset_keeps_the_size_and_view_it_rendered(needs_vulkan, tmp_path):
    from kitbench.evaluation.config import EvalConfig
    from kitbench.evaluation.runner import run_eval
    from kitbench.evaluation.suite import adhoc_suite

    settings = {"obs_mode": "rgb", "control_mode": "pd_ee_delta_pose", "camera_size": "32", "camera_view": "board"}
    suite = adhoc_suite(AK, 1, 3, **settings)
    data = tmp_path / "scored"
    run_eval(EvalConfig.of(suite, "expert", tmp_path / "report", save_dataset=data), progress=False)
    info = RecordingInfo.read(data)
    assert (info.camera_size, info.camera_view) == ("32x32", "board")
    assert "--camera-size 32x32 --camera-view board" in info.made_by
    report = json.loads((tmp_path / "report" / "report.json").read_text())
    assert (report["suite"]["camera_size"], report["suite"]["camera_view"]) == ("32x32", "board")
