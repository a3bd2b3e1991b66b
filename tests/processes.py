"""Killing a command the way a crash would, once it has committed some of its work."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path


def record_command(out: Path, task: str, *args: str) -> list[str]:
    """`kitbench record` as a user types it, run by this interpreter."""
    return [sys.executable, "-m", "kitbench.cli", "record", "--task", task, "--out", str(out), *args]


def kill_once_committed(cmd: list[str], out: Path, episodes: int = 2, timeout: float = 240) -> None:
    """Start `cmd`, and SIGKILL it as soon as the dataset at `out` lists `episodes` committed episodes."""
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        jsonl = out / "meta/kitbench_episodes.jsonl"
        if jsonl.is_file() and len(jsonl.read_text().splitlines()) >= episodes:
            break
        time.sleep(0.1)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
