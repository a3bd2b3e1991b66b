"""A stock lerobot command with the scripted leader arm at the controls (`play`): the command's own `main()`, what
its console script runs, with its flags in `sys.argv`, in the test's process, where the scripted teleoperators are
registered (`tests.teleop_devices`) and lerobot's key listener hands the script's key presses to lerobot's own
dispatch. Left out: lerobot's logging set-up (pytest keeps capturing) and, once the command is done, the signal
handlers it installed (lerobot-rollout's)."""

from __future__ import annotations

import importlib
import signal
import sys
from pathlib import Path
from typing import Any

import tests.teleop_devices as devices

ROOT = Path(__file__).resolve().parents[1]
COMMANDS = {
    "lerobot-record": "lerobot.scripts.lerobot_record",
    "lerobot-teleoperate": "lerobot.scripts.lerobot_teleoperate",
    "lerobot-rollout": "lerobot.scripts.lerobot_rollout",
}
SIGNALS = (signal.SIGINT, signal.SIGTERM)


def play(argv: list[str], reads: list[dict[str, Any]], monkeypatch, keys: dict[int, str] | None = None) -> int:
    """`argv` (a lerobot command and its flags) with the leader giving `reads` (the last held) and pressing `keys`
    (read index -> key); the reads it made."""
    from lerobot.utils import keyboard_input

    script = devices.Script(reads, keys or {})
    devices.SCRIPTS["default"] = script
    module = importlib.import_module(COMMANDS[argv[0]])
    monkeypatch.setattr(keyboard_input, "create_key_listener", devices.key_listener)
    monkeypatch.setattr(module, "init_logging", lambda *args, **kwargs: None)
    monkeypatch.setattr(sys, "argv", list(argv))
    handlers = {s: signal.getsignal(s) for s in SIGNALS}
    try:
        module.main()
    finally:
        for number, handler in handlers.items():
            signal.signal(number, handler)
        devices.SCRIPTS.clear()
    return script.position
