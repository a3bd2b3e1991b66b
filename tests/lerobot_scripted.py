"""A stock lerobot command with the scripted leader arm at the controls: the command's own `main()` (what its
console script runs) with its flags in `sys.argv`, where the scripted teleoperators are registered
(`tests.teleop_devices`) and lerobot's key listener hands the script's key presses to lerobot's own dispatch. `play`
runs one in the test's process (lerobot's logging set-up left out, so pytest keeps capturing); `run` in a process of
its own (`python -m tests.lerobot_scripted lerobot-rollout ...`), offline, for a command that takes over the
process's signals. A script: `{"reads": [{"<motor>.pos": deg, ...}, ...], "keys": {"<read index>": "left"}}`."""

from __future__ import annotations

import importlib
import json
import os
import subprocess
import sys
from pathlib import Path

from tests.lerobot_cli import OFFLINE

ROOT = Path(__file__).resolve().parents[1]
PLUGIN = ROOT / "integrations" / "lerobot_robot_kitbench"
SCRIPT_ENV = "KITBENCH_LEADER_SCRIPT"
COMMANDS = {
    "lerobot-record": "lerobot.scripts.lerobot_record",
    "lerobot-teleoperate": "lerobot.scripts.lerobot_teleoperate",
    "lerobot-rollout": "lerobot.scripts.lerobot_rollout",
}


def _install(script: dict) -> None:
    import tests.teleop_devices as devices

    keys = {int(k): v for k, v in script.get("keys", {}).items()}
    devices.SCRIPTS["default"] = devices.Script(script["reads"], keys)


def play(argv: list[str], script: dict, monkeypatch) -> None:
    """`argv` (a lerobot command and its flags) in this process with the leader playing `script`."""
    from lerobot.utils import keyboard_input

    import tests.teleop_devices as devices

    _install(script)
    module = importlib.import_module(COMMANDS[argv[0]])
    monkeypatch.setattr(keyboard_input, "create_key_listener", devices.key_listener)
    monkeypatch.setattr(module, "init_logging", lambda *args, **kwargs: None)
    monkeypatch.setattr(sys, "argv", list(argv))
    try:
        module.main()
    finally:
        devices.SCRIPTS.clear()


def run(argv: list[str], script: dict, where: Path, timeout: float = 120) -> str:
    """`argv` (a lerobot command and its flags) with the leader playing `script`, in a process of its own that
    imports this checkout and its plugin, offline; its output, or a failed assertion
    carrying it."""
    path = where / "leader_script.json"
    path.write_text(json.dumps(script))
    env = {**OFFLINE, SCRIPT_ENV: str(path), "PYTHONPATH": f"{ROOT}{os.pathsep}{PLUGIN}"}
    cmd = [sys.executable, "-m", "tests.lerobot_scripted", *argv]
    done = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=timeout, cwd=where)
    output = done.stdout + done.stderr
    assert done.returncode == 0, output[-4000:]
    return output


def main() -> None:
    from lerobot.utils import keyboard_input

    import tests.teleop_devices as devices

    command = sys.argv[1]
    _install(json.loads(Path(os.environ[SCRIPT_ENV]).read_text()))
    keyboard_input.create_key_listener = devices.key_listener  # the script presses the keys
    sys.argv = [command, *sys.argv[2:]]
    importlib.import_module(COMMANDS[command]).main()


if __name__ == "__main__":
    main()
