"""The scripted teleoperators' configs, registered in LeRobot's `TeleoperatorConfig` registry as a
`lerobot_teleoperator_*` plugin registers its own (the device class beside it, found by lerobot's factory)."""

from __future__ import annotations

from dataclasses import dataclass

from lerobot.teleoperators import TeleoperatorConfig
from lerobot.teleoperators.phone.config_phone import PhoneConfig


@TeleoperatorConfig.register_subclass("kitbench_replay_arm")
@dataclass
class ReplayArmConfig(TeleoperatorConfig):
    # A leader arm's serial port, named in messages as a real one is.
    port: str = "/dev/kitbench-replay"
    # The script it plays (tests.teleop_devices.SCRIPTS).
    script: str = "default"


@TeleoperatorConfig.register_subclass("kitbench_replay_gamepad")
@dataclass
class ReplayGamepadConfig(TeleoperatorConfig):
    script: str = "default"


@TeleoperatorConfig.register_subclass("kitbench_replay_phone")
@dataclass
class ReplayPhoneConfig(PhoneConfig):
    script: str = "default"
