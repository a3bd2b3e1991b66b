"""The SO-101: one kinematic model in SAPIEN and mink, drives that track, control modes in the real arm's units,
its LiftPegUpright and AssemblingKits variants and experts, and recordings in exactly the layout LeRobot's SO
follower declares."""

from __future__ import annotations

import json

import numpy as np
import pytest

from kitbench.control.kinematics import ArmKinematics, arm_joint_limits
from kitbench.errors import KitbenchError
from kitbench.geometry import pose_to_matrix
from kitbench.policies.joint_targets import joint_target_to_action
from kitbench.recording.config import RecordConfig
from kitbench.recording.recorder import record
from kitbench.registration import make_env
from kitbench.robots import ROBOTS

TASK = "LiftPegUpright-v1"
SPEC = ROBOTS["so101"]


def _env(mode: str = "pd_joint_pos", **kwargs):
    return make_env(TASK, obs_mode="state", control_mode=mode, robot_uids="so101", robot_init_qpos_noise=0.0, **kwargs)


def test_sapien_and_mink_agree_on_the_tcp():
    env = _env()
    u = env.unwrapped
    kinematics = ArmKinematics(SPEC)
    limits = arm_joint_limits(SPEC)
    rng = np.random.default_rng(0)
    base = pose_to_matrix(u.robot.base_pose.p, u.robot.base_pose.q)
    for _ in range(10):
        q = rng.uniform(limits[:, 0] * 0.9, limits[:, 1] * 0.9)
        u.robot.reset(q)
        tcp = u.robot.tcp_pose()
        sapien_tcp = pose_to_matrix(tcp.p, tcp.q)
        mink_tcp = base @ kinematics.tcp_pose(q)
        assert np.linalg.norm(sapien_tcp[:3, 3] - mink_tcp[:3, 3]) < 1e-4
        assert np.abs(sapien_tcp[:3, :3] - mink_tcp[:3, :3]).max() < 1e-4
    env.close()


def test_state_and_actions_are_in_the_so_followers_units():
    """Body joints in degrees, the jaw 0 (closed) .. 100 (open) over its range; actions convert back exactly."""
    env = _env()
    u = env.unwrapped
    env.reset(seed=0)
    q = u.robot.qpos()
    state = u.robot_state()
    assert np.allclose(state[:5], np.degrees(q[:5]), atol=1e-3)
    assert state[5] == pytest.approx(100.0, abs=0.5)  # reset opens the jaw fully
    assert list(u.action_space.low[5:]) == [0.0] and list(u.action_space.high[5:]) == [100.0]
    assert np.allclose(u.action_space.high[:5], np.degrees(arm_joint_limits(SPEC)[:, 1]), atol=1e-3)
    action = np.array([10.0, -20.0, 30.0, 40.0, -50.0, 25.0], dtype=np.float32)
    sim = u.action_to_sim(action)
    assert np.allclose(sim[:5], np.radians(action[:5]))
    assert sim[5] == pytest.approx(-0.5)  # 25% open: a quarter of the way from closed (-1) to open (1)
    assert np.allclose(u.action_from_sim(sim), action, atol=1e-4)
    target = action.copy()
    target[5] = 0.0
    for _ in range(6):
        env.step(target)
    state = u.robot_state()
    assert np.allclose(state[:5], target[:5], atol=0.5)  # degrees
    assert state[5] < 3.0  # closed
    env.close()


@pytest.mark.parametrize("joint", range(4))
def test_a_joint_step_is_done_within_two_control_periods(joint):
    env = _env()
    u = env.unwrapped
    env.reset(seed=0)
    start = u.robot_state().copy()
    target = start.copy()
    target[joint] += np.degrees(0.1)
    env.step(target)
    env.step(target)
    moved = (u.robot_state()[joint] - start[joint]) / np.degrees(0.1)
    assert 0.97 < moved < 1.03
    env.close()


def test_joint_delta_mode_moves_by_degrees():
    env = _env("pd_joint_delta_pos")
    u = env.unwrapped
    env.reset(seed=0)
    start = u.robot_state().copy()
    assert u.action_space.high[0] == pytest.approx(np.degrees(0.1), rel=1e-5)
    action = np.zeros(6, dtype=np.float32)
    action[1] = 4.0
    action[5] = 100.0  # stays open
    env.step(action)
    env.step(np.array([0, 0, 0, 0, 0, 100], dtype=np.float32))
    assert u.robot_state()[1] - start[1] == pytest.approx(4.0, abs=0.3)
    env.close()


def test_ee_delta_pose_tracks_position_and_the_reachable_rotations():
    """Five joints: the TCP's position and its roll about the approach axis are reached."""
    env = _env("pd_ee_delta_pose")
    u = env.unwrapped
    env.reset(seed=0)
    before = pose_to_matrix(u.robot.tcp_pose().p, u.robot.tcp_pose().q)
    action = np.zeros(7, dtype=np.float32)
    action[0] = 0.2  # 2 cm forward (ManiSkill's normalised delta: 1 is 0.1 m)
    action[6] = 100.0
    for _ in range(4):
        env.step(action if _ == 0 else np.array([0, 0, 0, 0, 0, 0, 100], dtype=np.float32))
    after = pose_to_matrix(u.robot.tcp_pose().p, u.robot.tcp_pose().q)
    assert np.allclose(after[:3, 3] - before[:3, 3], [0.02, 0.0, 0.0], atol=2e-3)
    # roll about the approach axis (the jaw points down at the ready pose: world z)
    before = after
    roll = np.zeros(7, dtype=np.float32)
    roll[5] = -1.0  # 0.1 rad about z: ManiSkill scales a rotation by -0.1
    roll[6] = 100.0
    env.step(roll)
    for _ in range(3):
        env.step(np.array([0, 0, 0, 0, 0, 0, 100], dtype=np.float32))
    after = pose_to_matrix(u.robot.tcp_pose().p, u.robot.tcp_pose().q)
    turned = np.arctan2(after[1, 0], after[0, 0]) - np.arctan2(before[1, 0], before[0, 0])
    assert (turned + np.pi) % (2 * np.pi) - np.pi == pytest.approx(0.1, abs=0.02)
    env.close()


def test_the_task_variant_is_half_size():
    env = _env()
    u = env.unwrapped
    for seed in range(5):
        env.reset(seed=seed)
        assert u.peg_scale == 0.5
        assert np.all(np.abs(u.peg.pose.p[:2]) <= 0.05)
    assert u.evaluate()["success"] is False
    env.close()


def _expert_episode(env, seed: int):
    """One episode of the task's SO-101 expert from `seed`, its targets sent in the env's mode: (last info, planner)."""
    u = env.unwrapped
    obs, info = env.reset(seed=seed)
    planner = u.make_expert()
    planner.reset(obs, info)
    for _ in range(u.episode_steps("so101")):
        target = planner.act(obs)
        obs, _, terminated, _, info = env.step(joint_target_to_action(env, target[:-1], float(target[-1])))
        if terminated:
            break
    return info, planner


@pytest.mark.parametrize("mode", ["pd_joint_pos", "pd_joint_delta_pos"])
def test_the_expert_stands_the_peg_up(mode):
    env = _env(mode)
    for seed in range(3):
        info, planner = _expert_episode(env, seed)
        assert info["success"], (seed, planner.failure)
    env.close()


def _so_follower_features(cameras: tuple[str, ...]) -> dict:
    """What `lerobot-record` writes for an SO-101 follower with these cameras (128x128 images)."""
    from lerobot.cameras.opencv.configuration_opencv import OpenCVCameraConfig
    from lerobot.robots.so_follower import SOFollowerRobotConfig
    from lerobot.robots.so_follower.so_follower import SOFollower
    from lerobot.utils.feature_utils import hw_to_dataset_features

    configs = {n: OpenCVCameraConfig(index_or_path=0, width=128, height=128, fps=20) for n in cameras}
    robot = SOFollower(SOFollowerRobotConfig(port="/dev/null", cameras=configs, id="kitbench"))
    return {
        **hw_to_dataset_features(robot.action_features, "action"),
        **hw_to_dataset_features(robot.observation_features, "observation", use_video=True),
    }


@pytest.mark.parametrize("obs_mode", ["state", "rgb"])
def test_a_recording_has_the_so_followers_features(tmp_path, obs_mode, request):
    if obs_mode == "rgb":
        request.getfixturevalue("needs_vulkan")
    out = tmp_path / "so101"
    config = RecordConfig.of(
        task=TASK, robot="so101", episodes=1, out=out, obs_mode=obs_mode, control_mode="pd_joint_pos"
    )
    record(config, progress=False)
    info = json.loads((out / "meta/info.json").read_text())
    assert info["robot_type"] == "so101"
    features = info["features"]
    expected = _so_follower_features(("front", "wrist") if obs_mode == "rgb" else ())
    for name, feature in expected.items():
        assert features[name]["dtype"] == feature["dtype"], name
        assert tuple(features[name]["shape"]) == tuple(feature["shape"]), name
        if feature["dtype"] != "video":
            assert features[name]["names"] == feature["names"], name
    camera_features = {n for n in features if n.startswith("observation.images.")}
    assert camera_features == {n for n in expected if n.startswith("observation.images.")}
    # the values are the SO follower's: degrees within the joints' ranges, the jaw within 0..100
    import pandas as pd

    frames = pd.concat(pd.read_parquet(p) for p in sorted((out / "data").rglob("*.parquet")))
    state = np.stack(frames["observation.state"].to_numpy())
    action = np.stack(frames["action"].to_numpy())
    limits = np.degrees(arm_joint_limits(SPEC))
    for values in (state, action):
        assert np.all(values[:, :5] >= limits[:, 0] - 1) and np.all(values[:, :5] <= limits[:, 1] + 1)
        assert np.all(values[:, 5] >= -1) and np.all(values[:, 5] <= 101)
    assert state[:, 5].max() > 90 and state[:, 5].min() < 40  # opened, then closed on the peg
    assert np.abs(state[:, :5]).max() > 10  # degrees, not radians
    card = (out / "README.md").read_text()
    assert "joints in degrees, `gripper.pos` 0 (closed) to 100 (open)" in card and "gripper opening (m)" not in card
    assert "- The task as built for the so101: the peg at 0.5 of the reference size (12 x 2.5 x 2.5 cm)" in card


def test_a_robot_a_task_does_not_support_names_its_robots(tmp_path):
    with pytest.raises(
        KitbenchError, match=r"robot 'fetch' is not supported by .*; valid choices: panda_wristcam, so101"
    ):
        make_env("AssemblingKits-v1", robot_uids="fetch")
    out = tmp_path / "never"
    with pytest.raises(KitbenchError, match="valid choices"):
        record(RecordConfig.of(task="AssemblingKits-v1", robot="fetch", episodes=1, out=out), progress=False)
    assert not out.exists()


def _kit_env(mode: str = "pd_joint_pos"):
    return make_env(
        "AssemblingKits-v1", obs_mode="state", control_mode=mode, robot_uids="so101", robot_init_qpos_noise=0.0
    )


def test_the_kit_variant_is_seven_tenths_size():
    from kitbench.kits import load_episodes, shape_geometry
    from kitbench.tasks.assembling_kits import ROBOT_VARIANTS

    env = _kit_env()
    u = env.unwrapped
    variant = ROBOT_VARIANTS["so101"]
    board = u.episodes.board
    assert board.scale == 0.7 and board.size == pytest.approx((0.14, 0.196)) and board.floor == pytest.approx(0.007)
    for seed in range(5):
        env.reset(seed=seed)
        shape = u.shape
        assert shape.scale == 0.7 and shape.height == pytest.approx(0.021)
        assert shape.area == pytest.approx(0.49 * shape_geometry(shape.shape_id).area)
        x, y = u.obj.pose.p[:2]
        assert variant.spawn_x[0] <= x <= variant.spawn_x[1] and variant.spawn_y[0] <= y <= variant.spawn_y[1]
        # the episode file's kit, every slot at 0.7 of its place and as turned; the goal on the smaller pocket's floor
        standard = load_episodes()[u.episode_index]
        for ours, theirs in zip(u.episode.slots, standard.slots, strict=True):
            assert ours.pos == pytest.approx((0.7 * theirs.pos[0], 0.7 * theirs.pos[1])) and ours.yaw == theirs.yaw
        assert u.goal_pos[2] == pytest.approx(0.007)
    geometry = u.episodes.board_geometry(u.episode_index)
    assert geometry.scale == 0.7 and geometry.top == pytest.approx(0.014)
    env.close()


def test_the_expert_inserts_the_smaller_shapes():
    env = _kit_env()
    u = env.unwrapped
    for seed in (1, 6, 8):  # a T block, a trapezoid, a kite
        info, planner = _expert_episode(env, seed)
        assert info["success"], (seed, u.shape.name, planner.failure)
    env.close()


@pytest.mark.parametrize("mode", ["pd_joint_pos", "pd_ee_delta_pose"])
def test_convert_turns_a_joint_delta_recording_into_another_mode_in_the_arms_units(tmp_path, mode):
    """A `pd_joint_delta_pos` recording (deltas in degrees, with noise) converted: every episode still succeeds and
    its stored actions, replayed from the seed in the new mode, succeed too (the jaw stays 0..100 throughout)."""
    import pandas as pd

    from kitbench.recording.convert import convert_config

    source = tmp_path / "src"
    config = RecordConfig.of(
        task=TASK, robot="so101", episodes=2, out=source, control_mode="pd_joint_delta_pos", action_noise=0.05
    )
    record(config, progress=False)
    out = tmp_path / mode
    summary = record(convert_config(source, out, control_mode=mode), progress=False)
    assert summary.stored == 2
    frames = pd.concat(pd.read_parquet(p) for p in sorted((out / "data").rglob("*.parquet")))
    executed = np.stack(frames["executed_action"].to_numpy())
    assert np.all(executed[:, -1] >= 0) and np.all(executed[:, -1] <= 100)
    episodes = [json.loads(x) for x in (out / "meta/kitbench_episodes.jsonl").open()]
    assert all(e["success"] for e in episodes)
    env = make_env(TASK, obs_mode="state", control_mode=mode, robot_uids="so101")
    for episode in episodes:
        env.reset(seed=episode["seed"])
        rows = frames["episode_index"].to_numpy().reshape(-1) == episode["episode_index"]
        for action in executed[rows]:
            _, _, terminated, _, info = env.step(action)
            if terminated:
                break
        assert info["success"]
    env.close()


def test_a_card_judges_joints_held_still_in_the_arms_units(tmp_path):
    """A joint jittering by 0.03 degrees (5e-4 rad) is held still; one moving by 0.1 degrees is not, though both
    are above the SI threshold read as degrees."""
    from kitbench.recording.card import STILL_STD, still_entries

    names = list(SPEC.state_names)
    std = [0.03, 0.1, 20.0, 20.0, 20.0, 30.0]
    (tmp_path / "meta").mkdir()
    (tmp_path / "meta/stats.json").write_text(json.dumps({"observation.state": {"std": std}}))
    info = {"robot_type": "so101", "features": {"observation.state": {"names": names}}}
    assert std[0] > STILL_STD and std[1] > STILL_STD
    assert still_entries(tmp_path, info) == {"observation.state": ["shoulder_pan.pos"]}


def test_the_lerobot_plugin_runs_the_so101_in_its_units():
    from lerobot.envs.factory import make_env as lerobot_make_env

    from lerobot_env_kitbench import KitbenchEnvConfig

    config = KitbenchEnvConfig(task=TASK, robot="so101", obs_type="pixels_state", control_mode="pd_joint_pos")
    shapes = {k: tuple(v.shape) for k, v in config.features.items() if not k.startswith("sensor_param")}
    assert shapes == {
        "action": (6,),
        "agent_pos": (6,),
        "environment_state": (7,),
        "pixels/front": (128, 128, 3),
        "pixels/wrist": (128, 128, 3),
    }
    envs = lerobot_make_env(KitbenchEnvConfig(task=TASK, robot="so101", control_mode="pd_joint_pos"), n_envs=1)
    envs = envs["kitbench"][0]
    try:
        obs, _ = envs.reset(seed=[0])
        start = obs["agent_pos"][0].copy()
        assert start[5] == pytest.approx(100.0, abs=0.5) and np.abs(start[:5]).max() > 10  # degrees, jaw open
        target = start.copy()
        target[0] += 5.0  # degrees
        for _ in range(3):
            obs, *_ = envs.step(target[None].astype(np.float32))
        assert obs["agent_pos"][0][0] == pytest.approx(target[0], abs=0.3)
    finally:
        envs.close()
