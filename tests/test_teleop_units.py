"""Teleoperation's parts without a recording: the device built from lerobot's registry (bad types and options in one
line), the leader-arm mapping on action dicts in lerobot's units, the end-effector mappings, the episode keys as
lerobot's listener delivers them, the real-time pacer, and the settings a teleoperated recording refuses."""

from __future__ import annotations

import time

import numpy as np
import pytest

import tests.teleop_devices  # noqa: F401  (registers the scripted teleoperators)
from kitbench.errors import KitbenchError
from kitbench.policies.joint_targets import joint_target_to_action
from kitbench.policies.registry import make_policy
from kitbench.registration import make_env
from kitbench.rollout import Control
from kitbench.teleop.checks import check_record_settings
from kitbench.teleop.keys import EpisodeKeys
from kitbench.teleop.mapping import DeltaMapping, JointMapping, PhoneMapping, commanded_tcp
from kitbench.teleop.pacing import Pacer

MOTORS = ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll")


@pytest.fixture(scope="module")
def so101():
    env = make_env("LiftPegUpright-v1", obs_mode="state", control_mode="pd_joint_pos", robot_uids="so101")
    env.reset(seed=0)
    yield env
    env.close()


def one_line(exc: pytest.ExceptionInfo) -> str:
    text = str(exc.value)
    assert "\n" not in text
    return text


# -- the device, from lerobot's registry ------------------------------------------------------------------------
def test_an_unknown_device_is_one_line_listing_lerobots_and_plugins_devices():
    with pytest.raises(KitbenchError) as exc:
        make_policy("teleop:no_such_device")
    text = one_line(exc)
    assert "unknown teleoperator 'no_such_device'; valid choices:" in text
    for known in ("so101_leader", "gamepad", "keyboard_ee", "phone", "kitbench_replay_arm"):
        assert known in text


def test_a_missing_required_option_names_it_and_the_flag():
    with pytest.raises(KitbenchError) as exc:
        make_policy("teleop:so101_leader")
    assert "teleop:so101_leader needs port (--policy-option port=...); valid options: port," in one_line(exc)


def test_an_unknown_option_lists_the_devices_and_kitbenchs_options():
    with pytest.raises(KitbenchError) as exc:
        make_policy("teleop:so101_leader", options={"port": "/dev/ttyACM0", "baud": 9600})
    text = one_line(exc)
    assert "teleop:so101_leader has no option 'baud'; valid options: port, use_degrees" in text
    assert "display" in text and "realtime" in text and "ee_speed" in text


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"display": "tv"}, "unknown teleop option display='tv'; valid choices: none, rerun, sapien"),
        ({"ee_speed": -1}, "teleop option ee_speed must be a number >= 1e-09, got -1"),
        ({"realtime": "yes"}, "teleop option realtime must be true or false, got 'yes'"),
        ({"display_save": "v.rrd"}, "display_save writes the Rerun view: it needs display=rerun"),
        ({"use_degrees": False}, "use_degrees=false reports joints from -100 to 100"),
    ],
)
def test_bad_values_of_options_are_one_line(options, message):
    with pytest.raises(KitbenchError) as exc:
        make_policy("teleop:so101_leader", options={"port": "/dev/ttyACM0", **options})
    assert message in one_line(exc)


def test_a_real_leader_arm_on_a_missing_port_is_one_line_naming_it_and_the_port():
    policy = make_policy("teleop:so101_leader", options={"port": "/dev/kitbench-no-such-port", "id": 7})
    assert policy.config.id == "7"  # a number given for a text field is text, as the command line meant it
    with pytest.raises(KitbenchError) as exc:
        policy.connect()
    assert one_line(exc).startswith("teleop:so101_leader on /dev/kitbench-no-such-port: cannot connect:")


def test_a_leader_arm_refuses_a_robot_without_its_motors():
    panda = make_env("LiftPegUpright-v1", obs_mode="state", control_mode="pd_joint_pos")
    try:
        with pytest.raises(KitbenchError) as exc:
            make_policy("teleop:kitbench_replay_arm").check(panda)
    finally:
        panda.close()
    text = one_line(exc)
    assert "drives no part of the panda: a leader arm must name its joints (panda_joint1" in text


def test_an_end_effector_device_refuses_a_joint_mode_naming_the_modes_that_take_it(so101):
    with pytest.raises(KitbenchError) as exc:
        make_policy("teleop:kitbench_replay_gamepad").check(so101)
    assert one_line(exc) == (
        "teleop:kitbench_replay_gamepad (end-effector deltas) cannot drive control_mode pd_joint_pos; valid "
        "choices: pd_ee_delta_pos, pd_ee_target_delta_pos, pd_ee_delta_pose, pd_ee_target_delta_pose "
        "(--control-mode)"
    )


# -- the leader arm, joint for joint ----------------------------------------------------------------------------
def test_a_leader_arms_degrees_and_jaw_percent_land_as_the_followers_joint_targets(so101):
    mapping = JointMapping(so101, joint_target_to_action)
    degrees = {"shoulder_pan": 12.5, "shoulder_lift": -30.0, "elbow_flex": 45.0, "wrist_flex": 60.0, "wrist_roll": -5}
    leader = {f"{m}.pos": v for m, v in degrees.items()} | {"gripper.pos": 30.0}
    arm, gripper = mapping.targets(leader)
    np.testing.assert_allclose(arm, np.radians(list(degrees.values())))
    assert gripper == pytest.approx(30 / 50 - 1)  # the simulation's command for 30% open (ManiSkill's: +1 open)
    action = mapping.action(so101, leader)  # pd_joint_pos: the same numbers, in the follower's units
    np.testing.assert_allclose(action, [*degrees.values(), 30.0], atol=1e-4)
    assert mapping.clips.total == 0 and mapping.clips.values == 12


def test_values_beyond_the_simulated_joint_limits_are_clipped_and_counted(so101):
    mapping = JointMapping(so101, joint_target_to_action)
    low, high = np.degrees(so101.robot.arm_limits[:, 0]), np.degrees(so101.robot.arm_limits[:, 1])
    leader = {f"{m}.pos": 0.0 for m in MOTORS} | {"gripper.pos": 50.0}
    leader["shoulder_pan.pos"] = high[0] + 15.0
    leader["elbow_flex.pos"] = low[2] - 1.0
    leader["gripper.pos"] = 120.0
    action = mapping.action(so101, leader)
    assert action[0] == pytest.approx(high[0], abs=1e-3) and action[2] == pytest.approx(low[2], abs=1e-3)
    assert action[5] == pytest.approx(100.0)
    mapping.action(so101, leader | {"gripper.pos": -4.0, "elbow_flex.pos": 0.0})
    assert dict(mapping.clips.clipped) == {"shoulder_pan.pos": 2, "elbow_flex.pos": 1, "gripper.pos": 2}
    assert mapping.clips.line() == (
        "5 of 12 values beyond the simulated joint limits clipped to them (shoulder_pan.pos 2, gripper.pos 2, "
        "elbow_flex.pos 1)"
    )


def test_a_leader_arm_drives_a_delta_mode_through_its_joint_targets():
    env = make_env("LiftPegUpright-v1", obs_mode="state", control_mode="pd_joint_delta_pos", robot_uids="so101")
    try:
        env.reset(seed=0)
        measured = np.degrees(env.robot.arm_qpos())
        leader = {f"{m}.pos": float(v) for m, v in zip(MOTORS, measured + [1.0, -2.0, 3.0, 0.5, -0.5], strict=True)}
        action = JointMapping(env, joint_target_to_action).action(env, leader | {"gripper.pos": 80.0})
        np.testing.assert_allclose(action[:5], [1.0, -2.0, 3.0, 0.5, -0.5], atol=1e-4)
        assert action[5] == pytest.approx(80.0)  # the jaw is absolute in every mode
    finally:
        env.close()


# -- end-effector devices -----------------------------------------------------------------------------------------
def test_gamepad_deltas_move_the_tcp_at_the_set_speed_and_its_classes_hold_the_gripper():
    env = make_env("LiftPegUpright-v1", obs_mode="state", control_mode="pd_ee_delta_pose")
    try:
        env.reset(seed=0)
        mapping = DeltaMapping(env, speed=0.2)  # 0.2 m/s at 20 Hz: 1 cm a step
        first = mapping.action(env, {"delta_x": 1.0, "delta_y": -0.5, "delta_z": 0.0, "gripper": 1.0})
        # 1 cm and -0.5 cm in ManiSkill's normalised deltas (1 is 0.1 m); no rotation; stays open (+1)
        np.testing.assert_allclose(first, [0.1, -0.05, 0, 0, 0, 0, 1], atol=1e-6)
        closed = mapping.action(env, {"delta_x": 0.0, "delta_y": 0.0, "delta_z": 0.0, "gripper": 0.0})
        held = mapping.action(env, {"delta_x": 0.0, "delta_y": 0.0, "delta_z": 0.0, "gripper": 1.0})
        opened = mapping.action(env, {"delta_x": 0.0, "delta_y": 0.0, "delta_z": 0.0, "gripper": 2.0})
        assert (closed[-1], held[-1], opened[-1]) == (-1.0, -1.0, 1.0)
    finally:
        env.close()


def test_a_phone_moves_the_tcp_from_where_it_was_commanded_when_enabled():
    from lerobot.teleoperators.phone.config_phone import PhoneOS
    from lerobot.utils.rotation import Rotation

    env = make_env("LiftPegUpright-v1", obs_mode="state", control_mode="pd_ee_pose")
    try:
        env.reset(seed=0)
        reference = commanded_tcp(env)
        mapping = PhoneMapping(env, PhoneOS.IOS, scale=0.5, gripper_speed=20.0)
        idle = {"phone.pos": np.zeros(3), "phone.rot": Rotation.from_rotvec(np.zeros(3)), "phone.enabled": False}
        held = mapping.action(env, idle | {"phone.raw_inputs": {}})
        np.testing.assert_allclose(held[:3], reference[:3, 3], atol=1e-6)  # never enabled: hold
        # lerobot's phone axes: the robot's x is the phone's -y, its y the phone's x
        moved = idle | {"phone.pos": np.array([0.02, -0.04, 0.0]), "phone.enabled": True}
        action = mapping.action(env, moved | {"phone.raw_inputs": {"a3": -1.0}})
        np.testing.assert_allclose(action[:3], reference[:3, 3] + [0.02, 0.01, 0.0], atol=1e-6)
        assert action[-1] == pytest.approx(80 / 50 - 1)  # the jaw closed 20% from open
    finally:
        env.close()


# -- the episode keys ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("keys", "control"),
    [
        (["right"], Control.NEXT),
        (["n"], Control.NEXT),
        (["left"], Control.RERECORD),
        (["R"], Control.RERECORD),
        (["esc"], Control.STOP),
        (["q"], Control.STOP),
        (["left", "esc"], Control.STOP),
        (["up", "x"], None),
    ],
)
def test_lerobot_records_keys_end_re_record_and_stop(keys, control):
    episode_keys = EpisodeKeys()
    for key in keys:
        episode_keys.press(key)
    assert episode_keys.take() is control
    assert episode_keys.take() is None  # taken once


def test_with_a_keyboard_device_only_letters_and_escape_count():
    episode_keys = EpisodeKeys(arrows=False)
    episode_keys.press("right")
    episode_keys.press("left")
    assert episode_keys.take() is None
    episode_keys.press("r")
    assert episode_keys.take() is Control.RERECORD


def test_without_a_display_or_a_terminal_the_keys_listen_to_nothing(monkeypatch):
    import io
    import sys

    from lerobot.utils import keyboard_input

    monkeypatch.setattr(keyboard_input, "pynput_can_capture", lambda: False)
    monkeypatch.setattr(sys, "stdin", io.StringIO())  # piped: no terminal to read keys from
    episode_keys = EpisodeKeys()
    episode_keys.start()  # lerobot's choice: no listener, the recording runs on (Ctrl-C still commits)
    assert episode_keys.listener is None
    episode_keys.stop()


# -- pacing ----------------------------------------------------------------------------------------------------------
class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.now += seconds


def paced(work: list[float], period: float = 0.05) -> Pacer:
    clock = FakeClock()
    pacer = Pacer(period, clock, clock.sleep)
    for seconds in work:
        pacer.wait()
        clock.now += seconds
    return pacer


def test_the_pacer_releases_once_a_period_when_the_loop_is_early():
    pacer = paced([0.02] * 20)
    np.testing.assert_allclose(pacer.intervals.seconds, [0.05] * 19)
    assert pacer.intervals.late == 0


def test_a_late_step_is_caught_up_within_a_period_and_a_stall_restarts_the_schedule():
    pacer = paced([0.01, 0.07, 0.01, 0.01, 0.3, 0.01, 0.01])
    np.testing.assert_allclose(pacer.intervals.seconds, [0.05, 0.07, 0.03, 0.05, 0.3, 0.05], atol=1e-9)
    assert pacer.intervals.late == 1


def test_a_new_episode_starts_at_once_and_its_pause_is_no_interval():
    clock = FakeClock()
    pacer = Pacer(0.05, clock, clock.sleep)
    pacer.wait()
    pacer.wait()
    clock.now += 5.0  # the episode is stored, the next one resets
    pacer.restart()
    started = clock.now
    pacer.wait()
    assert clock.now == started and len(pacer.intervals.seconds) == 1


def test_the_pacer_holds_the_period_on_the_wall_clock():
    pacer = Pacer(0.02)
    started = time.perf_counter()
    for _ in range(16):
        pacer.wait()
        time.sleep(0.004)  # the step's work
    elapsed = time.perf_counter() - started
    stats = pacer.intervals.stats()
    assert elapsed >= 15 * 0.02 * 0.95
    assert stats["median"] == pytest.approx(0.02, rel=0.25)


# -- what a teleoperated recording refuses ---------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("settings", "message"),
    [
        (
            {"executor": "ray"},
            "records in this process, where the person drives: record with --executor local (got ray)",
        ),
        ({"workers": 2}, "drives one episode at a time: record with --workers 1 (got 2)"),
        ({"shard_episodes": 10}, "records on one writer: record with --shard-episodes 0 (got 10)"),
        ({"action_noise": 0.5}, "stores what the person commanded: record with --action-noise 0 (got 0.5)"),
    ],
)
def test_a_teleoperated_recording_refuses_workers_ray_shards_and_noise(settings, message):
    given = {"workers": 1, "executor": "local", "shard_episodes": 0, "action_noise": 0.0} | settings
    with pytest.raises(KitbenchError) as exc:
        check_record_settings("teleop:so101_leader", **given)
    assert one_line(exc) == f"policy teleop:so101_leader {message}"
    check_record_settings("expert", **given)  # any other policy: as before


def test_rendering_for_the_view_leaves_the_simulation_as_it_was():
    """A recording with a live view builds its env with rendering on: the same states, step for step."""
    runs = []
    for render_mode in (None, "rgb_array"):
        env = make_env(
            "LiftPegUpright-v1", obs_mode="state", control_mode="pd_joint_delta_pos", render_mode=render_mode
        )
        try:
            env.reset(seed=3)
            rng = np.random.default_rng(0)
            states = [env.step(rng.uniform(-1, 1, env.action_space.shape))[0] for _ in range(15)]
        finally:
            env.close()
        runs.append(np.stack(states))
    np.testing.assert_array_equal(runs[0], runs[1])


KEYS_PROGRAM = """
import time
from kitbench.teleop.keys import EpisodeKeys
keys = EpisodeKeys()
keys.start()
print("listening" if keys.listener is not None else "no listener", flush=True)
deadline = time.monotonic() + 20
while time.monotonic() < deadline:
    control = keys.take()
    if control is not None:
        print(control.name, flush=True)
        if control.name == "STOP":
            break
    time.sleep(0.01)
keys.stop()
"""


def test_keys_typed_in_the_terminal_reach_the_episode_keys_through_lerobots_listener():
    """Without a display, lerobot's listener reads the terminal the recording runs in: the bytes a left arrow, an `n`
    and an Esc send arrive as lerobot-record's controls."""
    import os
    import pty
    import subprocess
    import sys

    master, terminal = pty.openpty()
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    process = subprocess.Popen(
        [sys.executable, "-c", KEYS_PROGRAM], stdin=terminal, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
        env=env, text=True,
    )  # fmt: skip
    os.close(terminal)
    try:
        assert process.stdout is not None
        assert process.stdout.readline().strip() == "listening"
        seen = []
        for typed in (b"\x1b[D", b"n", b"\x1b"):
            os.write(master, typed)
            line = ""
            while line not in ("RERECORD", "NEXT", "STOP"):  # lerobot says each key as it applies it
                line = process.stdout.readline().strip()
            seen.append(line)
        assert seen == ["RERECORD", "NEXT", "STOP"]
        assert process.wait(timeout=10) == 0
    finally:
        process.kill()
        os.close(master)
