"""A real X display: under Xvfb, keys typed with xdotool reach `kitbench record --policy teleop:kitbench_keyboard`
through LeRobot's own pynput listeners (the keyboard device's and the episode keys'): a held W moves the TCP
forward in the stored actions, the right arrow ends an episode past the task's step limit (kept), the left arrow
re-records the same seed, Esc stops and commits. Xvfb and xdotool come from `scripts/bootstrap-system.sh` (make),
pynput from the `keyboard` extra."""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from kitbench.registration import task_entry
from tests.processes import record_command

TASK = "LiftPegUpright-v1"
LIMIT = task_entry(TASK).env_class.episode_steps("panda")  # 50 steps, 2.5 s


@pytest.fixture(scope="module")
def display():
    """An Xvfb display of its own (the server picks a free number), with the RECORD extension pynput listens by."""
    if importlib.util.find_spec("pynput") is None:  # importing it needs the display
        pytest.skip("the keyboard extra (pynput) is not installed: make syncs every extra")
    missing = [tool for tool in ("Xvfb", "xdotool") if shutil.which(tool) is None]
    if missing:
        pytest.skip(f"{' and '.join(missing)} not installed (scripts/bootstrap-system.sh installs them)")
    read, write = os.pipe()
    server = subprocess.Popen(
        ["Xvfb", "-displayfd", str(write), "-screen", "0", "640x480x24", "+extension", "RECORD", "-nolisten", "tcp"],
        pass_fds=(write,),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    os.close(write)
    with os.fdopen(read) as numbers:
        number = numbers.readline().strip()
    if not number:
        server.kill()
        server.wait()
        pytest.skip("no X server could start (Xvfb exited without a display)")
    yield f":{number}"
    server.terminate()
    server.wait(timeout=10)


class Command:
    """`kitbench record` running on the display, its stderr lines collected as they come."""

    def __init__(self, argv: list[str], display: str):
        env = {**os.environ, "DISPLAY": display}
        env.pop("WAYLAND_DISPLAY", None)
        self.display = display
        self.proc = subprocess.Popen(argv, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        self.lines: list[str] = []
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()

    def _read(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            self.lines.append(line.rstrip("\n"))

    def wait_for(self, text: str, timeout: float = 120.0) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if any(text in line for line in self.lines):
                return
            if self.proc.poll() is not None:
                break
            time.sleep(0.02)
        raise AssertionError(f"no line with {text!r}; stderr:\n" + "\n".join(self.lines[-30:]))

    def xdotool(self, *args: str) -> None:
        subprocess.run(["xdotool", *args], env={**os.environ, "DISPLAY": self.display}, check=True, timeout=10)


def test_keys_typed_on_an_x_display_drive_the_recording(tmp_path, display):
    out = tmp_path / "out"
    argv = record_command(
        out, TASK, "--robot", "panda", "--control-mode", "pd_ee_target_delta_pose", "--episodes", "3",
        "--policy", "teleop:kitbench_keyboard",
    )  # fmt: skip
    cmd = Command(argv, display)
    try:
        cmd.wait_for("teleop: kitbench_keyboard connected")
        time.sleep(0.5)
        cmd.xdotool("key", "Left")  # re-record seed 0
        cmd.wait_for("seed 0: no success", timeout=30)
        started = time.monotonic()
        cmd.xdotool("keydown", "w")  # forward, held for a second
        time.sleep(1.0)
        cmd.xdotool("keyup", "w")
        time.sleep(max(0.0, started + 1.5 * LIMIT * 0.05 - time.monotonic()))  # well past the task's 2.5 s
        cmd.xdotool("key", "Right")  # end it, kept
        cmd.wait_for("ended early (next)", timeout=30)
        time.sleep(0.5)
        cmd.xdotool("key", "Escape")  # stop: seed 1 kept as it stands, committed
        assert cmd.proc.wait(timeout=120) == 0, "\n".join(cmd.lines[-30:])
    finally:
        if cmd.proc.poll() is None:
            cmd.proc.kill()
            cmd.proc.wait()
    err = "\n".join(cmd.lines)
    assert "seed 0: no success" in err and "discarded (re-record)" in err
    assert "stopped as asked (escape)" in err
    stored = [json.loads(line) for line in (out / "meta" / "kitbench_episodes.jsonl").read_text().splitlines()]
    assert [e["seed"] for e in stored] == [0, 1]  # seed 0 re-recorded once, not twice
    assert stored[0]["length"] > LIMIT and stored[0]["teleop"]["ended"] == "key"
    assert stored[0]["teleop"]["key"] == "right" and stored[1]["teleop"]["key"] == "esc"
    files = sorted((out / "data").rglob("*.parquet"))
    data = pd.concat([pd.read_parquet(f) for f in files]).sort_values(["episode_index", "frame_index"])
    actions = np.stack(data[data["episode_index"] == 0]["action"].to_numpy())
    # W held: +x at the full 0.1 m/s, 5 mm a step on the last target (0.05 of ManiSkill's normalised delta), alone
    forward = actions[:, 0] > 1e-4
    np.testing.assert_allclose(actions[forward, 0], 0.05, atol=1e-6)
    assert 14 <= forward.sum() <= 26, forward.sum()  # a second at 20 Hz, give or take the typing's timing
    np.testing.assert_allclose(actions[:, 1:6], 0.0, atol=1e-6)
    assert np.all(actions[:, 0] >= -1e-6)
    assert Path(out / "README.md").is_file()
