"""`kitbench_keyboard`: the keyboard with the turn, LeIsaac's SO-101 layout on lerobot's own keyboard listener
(`KeyboardTeleop`: pynput on an X11 desktop). While a key is held its axis is at full deflection:

| keys | | keys | |
|---|---|---|---|
| W / S | forward / back (+x / -x of the robot's base) | I / K | pitch: turn about the line between the fingers |
| A / D | left / right (+y / -y) | J / L | yaw: turn left / right about the vertical |
| Q / E | up / down (+z / -z) | U / O | open / close the hand |

The arrows and Esc stay lerobot-record's episode keys (next, re-record, stop); the letters are the arm's.
"""

from __future__ import annotations

from typing import Any

from lerobot.teleoperators.keyboard.teleop_keyboard import KeyboardTeleop

from kitbench.teleop.config_keyboard import KitbenchKeyboardConfig

# key -> (action entry, value while held)
BINDINGS: dict[str, tuple[str, float]] = {
    "w": ("delta_x", 1.0),
    "s": ("delta_x", -1.0),
    "a": ("delta_y", 1.0),
    "d": ("delta_y", -1.0),
    "q": ("delta_z", 1.0),
    "e": ("delta_z", -1.0),
    "i": ("delta_pitch", 1.0),
    "k": ("delta_pitch", -1.0),
    "j": ("delta_yaw", 1.0),
    "l": ("delta_yaw", -1.0),
    "u": ("gripper", 2.0),  # lerobot's gripper classes: 0 close, 1 stay, 2 open
    "o": ("gripper", 0.0),
}
NAMES = ("delta_x", "delta_y", "delta_z", "delta_pitch", "delta_yaw", "gripper")


def keys_to_action(held: set[str]) -> dict[str, float]:
    """The action of the keys `held` (lower-case letters): opposite keys together cancel out."""
    action = dict.fromkeys(NAMES, 0.0)
    action["gripper"] = 1.0  # stay
    for key in sorted(held):
        name, value = BINDINGS.get(key, (None, 0.0))
        if name == "gripper":
            action[name] = value
        elif name is not None:
            action[name] += value
    return action


class KitbenchKeyboard(KeyboardTeleop):
    config_class = KitbenchKeyboardConfig
    name = "kitbench_keyboard"

    @property
    def action_features(self) -> dict:
        return {"dtype": "float32", "shape": (len(NAMES),), "names": {n: i for i, n in enumerate(NAMES)}}

    def _on_release(self, key) -> None:
        """A release, queued as lerobot's listener queues it; Esc stays the recording's stop key and does not let
        go of the keyboard, as lerobot's does."""
        self.event_queue.put((getattr(key, "char", key), False))

    def held(self) -> set[str]:
        """The letters held now (lerobot's listener queues each press and release)."""
        self._drain_pressed_keys()
        return {k.lower() for k, down in self.current_pressed.items() if down and isinstance(k, str)}

    def get_action(self) -> dict[str, Any]:
        if not self.is_connected:
            raise ConnectionError(f"{self} is not connected (a keyboard needs pynput and an X11 desktop)")
        return keys_to_action(self.held())
