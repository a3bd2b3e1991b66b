"""The LeRobot robot plugin (`integrations/lerobot_robot_kitbench`, `--robot.type=kitbench_so101`): the simulated
SO-101 as a LeRobot `Robot`, built by lerobot's own factory after its plugin discovery, in the real follower's
layout; its `Robot` API round trip in the follower's units; lerobot-teleoperate's own loop driving it with a
scripted leader arm until the scene resets itself at success."""

from __future__ import annotations

import numpy as np
import pytest

import tests.teleop_devices as devices
from kitbench.errors import KitbenchError
from tests.test_teleop_record import expert


@pytest.fixture(scope="module")
def registry():
    from lerobot.robots import RobotConfig
    from lerobot.utils.import_utils import register_third_party_plugins

    register_third_party_plugins()  # as every lerobot command does first
    return RobotConfig


def make_robot(registry, **settings):
    from lerobot.robots import make_robot_from_config

    return make_robot_from_config(registry.get_choice_class("kitbench_so101")(**settings))


def test_its_features_are_the_real_followers(registry):
    from lerobot.robots.so_follower import SO101Follower, SO101FollowerConfig

    follower = SO101Follower(SO101FollowerConfig(port="/dev/kitbench-none"))  # not connected: features only
    robot = make_robot(registry)
    assert type(robot).__name__ == "KitbenchSO101" and robot.name == "kitbench_so101"
    assert robot.action_features == follower.action_features
    motors = dict.fromkeys(follower.action_features, float)
    assert robot.observation_features == {**motors, "front": (128, 128, 3), "wrist": (128, 128, 3)}
    assert make_robot(registry, obs_mode="state", camera_size="64x48").observation_features == motors
    assert make_robot(registry, camera_size="64x48").cameras == {"front": (48, 64, 3), "wrist": (48, 64, 3)}


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        ({"task": "NoSuchTask-v1"}, "unknown task 'NoSuchTask-v1'; valid choices:"),
        ({"obs_mode": "depth"}, "unknown obs_mode 'depth'; valid choices: rgb, state"),
        ({"camera_size": "4x4"}, "camera_size must be WIDTHxHEIGHT or one side"),
        ({"max_relative_target": -1.0}, "max_relative_target must be a number > 0"),
    ],
)
def test_bad_settings_are_one_line(registry, settings, message):
    with pytest.raises(KitbenchError, match=message):
        registry.get_choice_class("kitbench_so101")(**settings)


def test_the_robot_api_round_trip_in_the_followers_units(registry):
    from lerobot.utils.errors import DeviceNotConnectedError

    robot = make_robot(registry, obs_mode="state", realtime=False)
    with pytest.raises(DeviceNotConnectedError):
        robot.get_observation()
    robot.connect()
    try:
        start = robot.get_observation()
        assert set(start) == set(robot.observation_features)
        assert all(isinstance(v, float) for v in start.values())
        assert start["gripper.pos"] == pytest.approx(100.0, abs=1.0)  # the jaw starts open
        goal = dict(start) | {"shoulder_pan.pos": start["shoulder_pan.pos"] + 20.0, "gripper.pos": 40.0}
        for _ in range(10):
            sent = robot.send_action(goal)
        assert sent == pytest.approx(goal)
        reached = robot.get_observation()
        assert reached["shoulder_pan.pos"] == pytest.approx(goal["shoulder_pan.pos"], abs=1.0)  # degrees
        assert reached["gripper.pos"] == pytest.approx(40.0, abs=2.0)  # jaw percent
        # beyond the joint's range: clipped, and the goal sent says so
        high = float(np.degrees(robot.env.robot.arm_limits[0, 1]))
        assert robot.send_action({"shoulder_pan.pos": high + 40.0})["shoulder_pan.pos"] == pytest.approx(high, abs=1e-3)
    finally:
        robot.disconnect()
    assert not robot.is_connected


def test_goals_are_capped_as_the_followers_max_relative_target_caps_them(registry):
    robot = make_robot(registry, obs_mode="state", realtime=False, max_relative_target=5.0)
    robot.connect()
    try:
        start = robot.get_observation()
        sent = robot.send_action({"elbow_flex.pos": start["elbow_flex.pos"] + 30.0})
        assert sent == {"elbow_flex.pos": pytest.approx(start["elbow_flex.pos"] + 5.0)}
    finally:
        robot.disconnect()


def test_lerobot_teleoperate_drives_it_with_a_leader_arm_until_the_scene_resets_at_success(registry, monkeypatch):
    from lerobot.processor import make_default_processors
    from lerobot.scripts.lerobot_teleoperate import teleop_loop
    from lerobot.teleoperators import make_teleoperator_from_config

    from tests.teleop_devices.config_replay import ReplayArmConfig

    truth = expert(0)
    devices.SCRIPTS["default"] = devices.Script(truth.reads[1:])  # lerobot's loop has no start-pose wait
    robot = make_robot(registry, obs_mode="state", realtime=False, settle_steps=0)
    teleop = make_teleoperator_from_config(ReplayArmConfig())
    robot.connect()
    teleop.connect()
    try:
        steps = len(truth.actions)
        teleop_loop(teleop, robot, 20, *make_default_processors(), duration=(steps + 10) / 20)
        assert robot.scenes >= 1 and robot.seed >= 1  # the expert's success reset the scene, on the next seed
    finally:
        teleop.disconnect()
        robot.disconnect()
        devices.SCRIPTS.clear()
