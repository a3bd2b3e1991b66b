"""The configs of kitbench's own teleoperators, registered in LeRobot's `TeleoperatorConfig` registry as a
`lerobot_teleoperator_*` plugin registers its own (lerobot's factory finds each device class in the module named
after the config's: `kitbench.teleop.keyboard`, `kitbench.teleop.gamepad`)."""

from __future__ import annotations

from dataclasses import dataclass

from lerobot.teleoperators import TeleoperatorConfig


@TeleoperatorConfig.register_subclass("kitbench_keyboard")
@dataclass
class KitbenchKeyboardConfig(TeleoperatorConfig):
    """The keyboard with the turn (LeIsaac's SO-101 layout): nothing to set (its speeds are the source's
    `ee_speed` and `turn_speed`)."""
