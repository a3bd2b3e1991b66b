"""Scripted LeRobot teleoperators for the teleoperation tests: each plays a `Script` of `get_action` results (a
leader arm's `<motor>.pos`, a gamepad's deltas, a phone's pose), may press lerobot-record's keys at given reads,
fail to connect, or fail at a given read as an unplugged device does. Registered through LeRobot's
`TeleoperatorConfig` registry (`config_replay`), built by lerobot's own factory, as a real device is."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import pytest
from lerobot.teleoperators import Teleoperator

from tests.teleop_devices.config_replay import ReplayArmConfig, ReplayGamepadConfig, ReplayPhoneConfig

SO101_MOTORS = ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll", "gripper")


@dataclass
class Script:
    reads: list[dict[str, Any]]  # what each get_action returns, in order; the last is held once they run out
    keys: dict[int, str] = field(default_factory=dict)  # read index -> key pressed during that read
    fail_at: int | None = None  # the read that fails as an unplugged serial port does
    missing: bool = False  # connect() fails: no device on the port
    events: dict[int, str] = field(default_factory=dict)  # read index -> lerobot TeleopEvents member pressed then
    position: int = 0  # reads made


SCRIPTS: dict[str, Script] = {}
# the episode keys' dispatch, as lerobot's listener calls it (tests install `key_listener` in its place)
KEYBOARD: dict[str, Any] = {"dispatch": None}


class FakeListener:
    def stop(self) -> None:
        KEYBOARD["dispatch"] = None


def key_listener(dispatch, controls_help: str = ""):
    """Stands in for `lerobot.utils.keyboard_input.create_key_listener`: keeps the dispatch for scripted keys."""
    KEYBOARD["dispatch"] = dispatch
    return FakeListener()


class _Replay(Teleoperator):
    """What the three share: connect, read the script, press its keys, fail where it says."""

    def __init__(self, config):
        super().__init__(config)
        self.config = config
        self.connected = False

    @property
    def script(self) -> Script:
        return SCRIPTS[self.config.script]

    @property
    def feedback_features(self) -> dict:
        return {}

    @property
    def is_connected(self) -> bool:
        return self.connected

    def connect(self, calibrate: bool = True) -> None:
        if self.script.missing:
            raise ConnectionError(f"Could not connect on port '{getattr(self.config, 'port', '?')}'")
        self.connected = True

    @property
    def is_calibrated(self) -> bool:
        return True

    def calibrate(self) -> None:
        pass

    def configure(self) -> None:
        pass

    def get_action(self) -> dict[str, Any]:
        if not self.connected:
            raise ConnectionError("not connected")
        script = self.script
        i = script.position
        script.position += 1
        if script.fail_at is not None and i >= script.fail_at:
            self.connected = False
            raise OSError("device reports readiness to read but returned no data (device disconnected?)")
        if i in script.keys and KEYBOARD["dispatch"] is not None:
            KEYBOARD["dispatch"](script.keys[i])
        return dict(script.reads[min(i, len(script.reads) - 1)])

    def send_feedback(self, feedback: dict[str, Any]) -> None:
        pass

    def disconnect(self) -> None:
        self.connected = False


class ReplayArm(_Replay):
    """A leader arm: the SO-101's motors, degrees and jaw percent."""

    config_class = ReplayArmConfig
    name = "kitbench_replay_arm"

    @property
    def action_features(self) -> dict:
        return {f"{motor}.pos": float for motor in SO101_MOTORS}


class ReplayGamepad(_Replay):
    """A gamepad: position deltas and lerobot's gripper classes, declared as lerobot's gamepad declares them, and its
    episode buttons as lerobot's gamepad reports them (`get_teleop_events`: X sets re-record and terminate)."""

    config_class = ReplayGamepadConfig
    name = "kitbench_replay_gamepad"

    def get_teleop_events(self) -> dict:
        from lerobot.teleoperators.utils import TeleopEvents

        pressed = self.script.events.get(self.script.position - 1)
        events = dict.fromkeys(TeleopEvents, False)
        if pressed is not None:
            events[TeleopEvents[pressed]] = True
            if pressed == "RERECORD_EPISODE":
                events[TeleopEvents.TERMINATE_EPISODE] = True
        return events

    @property
    def action_features(self) -> dict:
        return {"dtype": "float32", "shape": (4,), "names": {"delta_x": 0, "delta_y": 1, "delta_z": 2, "gripper": 3}}


class ReplayPhone(_Replay):
    """A phone: its pose since the enabling press, and its buttons."""

    config_class = ReplayPhoneConfig
    name = "kitbench_replay_phone"

    @property
    def action_features(self) -> dict:
        return {"phone.pos": object, "phone.rot": object, "phone.raw_inputs": dict, "phone.enabled": bool}


@pytest.fixture(autouse=True)
def scripted_keys(monkeypatch):
    """lerobot's key listener, as the episode keys start it, keeps its dispatch for the scripts' key presses; each
    test starts with no scripts. Autouse in a test module that imports it."""
    from lerobot.utils import keyboard_input

    monkeypatch.setattr(keyboard_input, "create_key_listener", key_listener)
    SCRIPTS.clear()
    yield
    SCRIPTS.clear()
