"""The config of kitbench's gamepad with the turn, in LeRobot's `TeleoperatorConfig` registry (its device class is
`kitbench.teleop.gamepad.KitbenchGamepad`, which lerobot's factory finds by the module's name)."""

from __future__ import annotations

from dataclasses import dataclass

from lerobot.teleoperators import TeleoperatorConfig
from lerobot.teleoperators.gamepad.configuration_gamepad import GamepadTeleopConfig


@TeleoperatorConfig.register_subclass("kitbench_gamepad")
@dataclass
class KitbenchGamepadConfig(GamepadTeleopConfig):
    """lerobot's gamepad's settings (`use_gripper`, `hidapi_fallback`)."""
