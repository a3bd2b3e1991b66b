"""The teleop source's own options (`--policy-option KEY=VALUE`), beside the device's config fields: the live view,
real-time pacing, and how end-effector devices and the start pose are handled. Each bad value is one line."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from kitbench.errors import KitbenchError
from kitbench.teleop.view import DISPLAYS


@dataclass(frozen=True)
class TeleopOptions:
    # The live view: none, rerun (lerobot's --display_data) or sapien (a viewer window).
    display: str = "none"
    # A Rerun server to stream to (lerobot's --display_ip / --display_port); default: a spawned viewer.
    display_ip: str | None = None
    display_port: int | None = None
    # An .rrd file to write the Rerun view to instead (a machine without a display; `rerun <file>` opens it).
    display_save: str | None = None
    # The Rerun view's third-person image, pixels square (0: none; None: 192 where the observation has no camera
    # image, else none: a third render a step breaks the 20 Hz pacing on 2 CPU cores, docs/teleoperation.md).
    display_scene: int | None = None
    # Step at the task's control rate in wall-clock time (false: as fast as the device answers).
    realtime: bool = True
    # End-effector deltas: the TCP's speed at full deflection, m/s.
    ee_speed: float = 0.1
    # End-effector deltas with the turn (kitbench_keyboard, kitbench_gamepad): the turn's speed at full deflection,
    # rad/s.
    turn_speed: float = 0.6
    # A phone: metres the TCP moves per metre the phone moves.
    phone_scale: float = 1.0
    # A phone: jaw percent a control step per unit of gripper velocity.
    gripper_speed: float = 20.0
    # A leader arm: each episode starts once every joint is within this many degrees of the simulated arm's
    # (0: at once).
    align: float = 10.0
    # The longest an episode may run, seconds (None: until the person ends it or success does, as LeIsaac turns the
    # time-out off while a person drives); the task's own step limit does not apply to a person's episodes.
    max_seconds: float | None = None

    @property
    def save_path(self) -> Path | None:
        return None if self.display_save is None else Path(self.display_save)


NAMES = tuple(f.name for f in dataclasses.fields(TeleopOptions))


def _number(name: str, value: Any, minimum: float, integer: bool = False) -> None:
    number = isinstance(value, int) if integer else isinstance(value, int | float)
    if isinstance(value, bool) or not number or not math.isfinite(value) or value < minimum:
        what = "an integer" if integer else "a number"
        raise KitbenchError(f"teleop option {name} must be {what} >= {minimum:g}, got {value!r}")


def split_options(options: dict[str, Any]) -> tuple[TeleopOptions, dict[str, Any]]:
    """kitbench's own options, checked, and the rest (the device's)."""
    own = {k: v for k, v in options.items() if k in NAMES}
    device = {k: v for k, v in options.items() if k not in NAMES}
    display = own.get("display", "none")
    if display not in DISPLAYS:
        raise KitbenchError(f"unknown teleop option display={display!r}; valid choices: {', '.join(DISPLAYS)}")
    if not isinstance(own.get("realtime", True), bool):
        raise KitbenchError(f"teleop option realtime must be true or false, got {own['realtime']!r}")
    if own.get("max_seconds") is not None:
        _number("max_seconds", own["max_seconds"], 1e-9)
    for name in ("ee_speed", "turn_speed", "phone_scale", "gripper_speed"):
        if name in own:
            _number(name, own[name], 1e-9)
    for name in ("align", "display_scene"):
        if own.get(name) is not None:
            _number(name, own[name], 0, integer=name == "display_scene")
    if "display_port" in own:
        _number("display_port", own["display_port"], 1, integer=True)
    for name in ("display_ip", "display_save"):
        if name in own:
            own[name] = str(own[name])
    if own.get("display_save") and display != "rerun":
        raise KitbenchError("teleop option display_save writes the Rerun view: it needs display=rerun")
    return TeleopOptions(**own), device
