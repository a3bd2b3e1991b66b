"""`kitbench_gamepad`: lerobot's gamepad (`GamepadTeleop`, pygame) with the turn. lerobot's sticks move the TCP
(left stick: x and y, right stick up/down: z) and its buttons hold the hand (RB close, LT open: lerobot's) and end
episodes (Y next, X re-record, A stop: `kitbench.teleop.keys.DEVICE_EVENTS`); the right stick left/right turns it
about the vertical (yaw) and the D-pad up/down about the line between the fingers (pitch).
"""

from __future__ import annotations

from typing import Any

from lerobot.teleoperators.gamepad.teleop_gamepad import GamepadTeleop, gripper_action_map

from kitbench.teleop.config_gamepad import KitbenchGamepadConfig
from kitbench.teleop.keyboard import NAMES

YAW_AXIS = 2  # the right stick's horizontal axis (lerobot reads its vertical, 3, for z)


class KitbenchGamepad(GamepadTeleop):
    config_class = KitbenchGamepadConfig
    name = "kitbench_gamepad"

    @property
    def action_features(self) -> dict:
        return {"dtype": "float32", "shape": (len(NAMES),), "names": {n: i for i, n in enumerate(NAMES)}}

    def get_action(self) -> dict[str, Any]:
        if self.gamepad is None:
            raise ConnectionError(f"{self} is not connected")
        controller = self.gamepad
        controller.update()
        joystick = controller.joystick
        if joystick is None:
            raise ConnectionError("no gamepad detected (pygame sees no joystick)")
        dx, dy, dz = controller.get_deltas()
        yaw = -float(joystick.get_axis(YAW_AXIS))
        yaw = 0.0 if abs(yaw) < controller.deadzone else yaw
        pitch = float(joystick.get_hat(0)[1]) if joystick.get_numhats() else 0.0
        gripper = gripper_action_map[controller.gripper_command()] if self.config.use_gripper else 1
        return {
            "delta_x": float(dx),
            "delta_y": float(dy),
            "delta_z": float(dz),
            "delta_pitch": pitch,
            "delta_yaw": yaw,
            "gripper": float(gripper),
        }
