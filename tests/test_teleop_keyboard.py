"""kitbench's keyboard and gamepad with the turn can finish both tasks: a scripted stream of keys (pressed and
released through the keyboard's own listener callbacks) and of sticks (read by the gamepad's own `get_action` from
a stand-in joystick), derived from the expert's TCP path, drives the Panda through the device class, kitbench's
mapping, the joint-speed limit and the recorder's episode loop to success on a LiftPegUpright and an
AssemblingKits seed. Plus the keys' layout and the turn's geometry."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

import tests.teleop_devices as devices
from kitbench.geometry import matrix_to_axis_angle
from kitbench.policies.registry import make_policy
from kitbench.recording.rollout import run_episode
from kitbench.registration import NO_STEP_LIMIT, make_env
from kitbench.rollout import Hook
from kitbench.teleop.keyboard import BINDINGS, KitbenchKeyboard, keys_to_action
from kitbench.teleop.mapping import TurnMapping, commanded_tcp
from tests.teleop_streams import AXES, expert_waypoints, follow

pytest.importorskip("pygame", reason="the gamepad extra (pygame) is not installed: make syncs every extra")
from lerobot.teleoperators.gamepad.gamepad_utils import GamepadController

from kitbench.teleop.gamepad import YAW_AXIS, KitbenchGamepad

MODE = "pd_ee_delta_pose"
CASES = {"LiftPegUpright-v1": ("panda", 0), "AssemblingKits-v1": ("panda_wristcam", 0)}
STEP, TURN = 0.1 * 0.05, 0.6 * 0.05  # the default ee_speed and turn_speed, a 20 Hz step


@pytest.fixture(autouse=True)
def scripted_keys(monkeypatch):
    from lerobot.utils import keyboard_input

    monkeypatch.setattr(keyboard_input, "create_key_listener", devices.key_listener)


# -- the stand-in hardware: the device classes' own reading of it is what runs -----------------------------------
class ScriptedKeyboard(KitbenchKeyboard):
    """The keyboard without an X display: its listener's callbacks get the scripted presses and releases."""

    up = False

    def connect(self, calibrate: bool = True) -> None:
        self.up = True

    @property
    def is_connected(self) -> bool:
        return self.up

    def disconnect(self) -> None:
        self.up = False

    def play(self, deltas: dict[str, float]) -> None:
        wanted = {k for k, (name, value) in BINDINGS.items() if deltas.get(name) == value}
        held = {k for k, down in self.current_pressed.items() if down}
        for key in sorted(held - wanted):
            self._on_release(SimpleNamespace(char=key))  # as pynput's KeyCode gives a letter
        for key in sorted(wanted - held):
            self._on_press(SimpleNamespace(char=key))


class Joystick:
    """pygame's joystick as lerobot's gamepad reads it: axes, a D-pad hat, buttons."""

    def __init__(self) -> None:
        self.axes = [0.0] * 4
        self.hat = (0, 0)

    def get_axis(self, i: int) -> float:
        return self.axes[i]

    def get_numhats(self) -> int:
        return 1

    def get_hat(self, i: int) -> tuple[int, int]:
        return self.hat

    def get_button(self, i: int) -> bool:
        return False


class ScriptedController(GamepadController):
    """lerobot's pygame controller with the sticks and buttons set by the script instead of pygame's events."""

    def __init__(self) -> None:
        super().__init__()
        self.joystick = Joystick()

    def update(self) -> None:
        """The state is what `play` set."""


class ScriptedGamepad(KitbenchGamepad):
    def connect(self) -> None:
        self.gamepad = ScriptedController()

    def play(self, deltas: dict[str, float]) -> None:
        pad = self.gamepad
        assert isinstance(pad, ScriptedController)
        axes = pad.joystick.axes
        # lerobot's gamepad: delta_x = -axis 1, delta_y = -axis 0, delta_z = -axis 3; kitbench's yaw = -axis 2
        axes[1], axes[0], axes[3] = -deltas["delta_x"], -deltas["delta_y"], -deltas["delta_z"]
        axes[YAW_AXIS] = -deltas["delta_yaw"]
        pad.joystick.hat = (0, int(deltas["delta_pitch"]))
        pad.close_gripper_command = deltas["gripper"] == 0.0  # RB held
        pad.open_gripper_command = deltas["gripper"] == 2.0  # LT held


DEVICES = {"kitbench_keyboard": ScriptedKeyboard, "kitbench_gamepad": ScriptedGamepad}


class Play(Hook):
    """Before each step, the stream's entry for it goes to the device's hardware stand-in."""

    def __init__(self, device, stream: list[dict[str, float]]):
        self.device, self.stream = device, stream

    def before_act(self, episode) -> None:
        self.device.play(self.stream[min(episode.steps, len(self.stream) - 1)])


@pytest.fixture(scope="module")
def streams() -> dict[str, list[dict[str, float]]]:
    out = {}
    for task, (robot, seed) in CASES.items():
        points = expert_waypoints(task, robot, seed, MODE)
        out[task] = follow(points, STEP, TURN, lower=4)
    return out


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("task", CASES)
def test_a_scripted_stream_through_the_device_finishes_the_task(device, task, streams):
    robot, seed = CASES[task]
    stream = streams[task]
    assert any(s["delta_yaw"] for s in stream) or any(s["delta_pitch"] for s in stream)  # the turn is used
    policy = make_policy(f"teleop:{device}", options={"realtime": False, "max_seconds": 0.05 * len(stream) + 2})
    policy.device = DEVICES[device](policy.config)
    env = make_env(task, obs_mode="state", control_mode=MODE, robot_uids=robot, max_episode_steps=NO_STEP_LIMIT)
    try:
        policy.connect()
        record = run_episode(env, policy, seed, hooks=(Play(policy.device, stream), *policy.episode_hooks()))
    finally:
        policy.disconnect()
        env.close()
    assert record.success, f"{device} on {task}: {record.length} of {len(stream)} steps, no success"
    assert record.teleop is not None and record.teleop["ended"] == "success"


# -- the layout and the geometry ---------------------------------------------------------------------------------
def test_the_keys_layout_is_leisaacs_and_opposite_keys_cancel():
    assert keys_to_action({"w", "a", "q"}) == {
        "delta_x": 1.0,
        "delta_y": 1.0,
        "delta_z": 1.0,
        "delta_pitch": 0.0,
        "delta_yaw": 0.0,
        "gripper": 1.0,
    }
    assert keys_to_action({"s", "d", "e", "k", "l", "o"})["delta_yaw"] == -1.0
    assert keys_to_action({"w", "s"})["delta_x"] == 0.0
    assert keys_to_action({"u"})["gripper"] == 2.0 and keys_to_action({"o"})["gripper"] == 0.0
    assert set(AXES) <= {name for name, _ in BINDINGS.values()}


def test_the_turn_keys_pitch_about_the_fingers_line_and_yaw_about_the_vertical():
    env = make_env("LiftPegUpright-v1", obs_mode="state", control_mode=MODE, robot_uids="panda")
    try:
        env.reset(seed=0)
        mapping = TurnMapping(env, 0.1, 0.6)
        start = commanded_tcp(env)
        yawed = mapping.target(start, {"delta_yaw": 1.0, "delta_x": -1.0})
        np.testing.assert_allclose(yawed[:3, 3] - start[:3, 3], [-0.005, 0, 0], atol=1e-12)
        np.testing.assert_allclose(matrix_to_axis_angle(yawed[:3, :3] @ start[:3, :3].T), [0, 0, 0.03], atol=1e-9)
        pitched = mapping.target(start, {"delta_pitch": -1.0})
        turn = matrix_to_axis_angle(start[:3, :3].T @ pitched[:3, :3])  # in the TCP's own frame
        np.testing.assert_allclose(turn, [0, -0.03, 0], atol=1e-9)
        # the env's action reaches that target: the controller's commanded TCP after the step
        env.step(mapping.action(env, {"delta_yaw": 1.0}))
        np.testing.assert_allclose(commanded_tcp(env), mapping.target(start, {"delta_yaw": 1.0}), atol=1e-6)
    finally:
        env.close()


def test_without_the_turn_the_same_stream_does_not_stand_the_peg_upright(streams):
    task = "LiftPegUpright-v1"
    robot, seed = CASES[task]
    flat = [s | {"delta_pitch": 0.0, "delta_yaw": 0.0} for s in streams[task]]
    policy = make_policy("teleop:kitbench_keyboard", options={"realtime": False, "max_seconds": 0.05 * len(flat)})
    policy.device = ScriptedKeyboard(policy.config)
    env = make_env(task, obs_mode="state", control_mode=MODE, robot_uids=robot, max_episode_steps=NO_STEP_LIMIT)
    try:
        policy.connect()
        record = run_episode(env, policy, seed, hooks=(Play(policy.device, flat), *policy.episode_hooks()))
    finally:
        policy.disconnect()
        env.close()
    assert not record.success and record.teleop is not None and record.teleop["ended"] == "limit"
