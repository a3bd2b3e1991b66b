"""What a recording did (`Summary`: stored, attempted, speed, why it stopped) and the attempt limit."""

from __future__ import annotations

import signal
import time
from dataclasses import dataclass
from pathlib import Path

ATTEMPTS_PER_EPISODE = 10  # default --max-attempts: this many attempts per episode asked for


def attempt_limit(config) -> int:
    """Episodes a recording attempts, stored or not, before it gives up (`max_attempts`, else 10 per episode)."""
    return config.demo.max_attempts or ATTEMPTS_PER_EPISODE * config.episodes


def folder_size(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file()) if path.exists() else 0


@dataclass
class Summary:
    stored: int = 0
    attempted: int = 0
    successes: int = 0
    failures_dropped: int = 0
    frames: int = 0
    seconds: float = 0.0
    size_bytes: int = 0
    interrupted: bool = False
    signal: int | None = None  # the signal that interrupted the run (SIGINT for Ctrl-C)
    gave_up: bool = False  # stopped at max_attempts before storing every episode
    physics_errors: int = 0  # attempts dropped because the simulation failed (info["physics_error"])
    rejected: int = 0  # converted episodes not stored because they did not reproduce their source

    @property
    def exit_code(self) -> int:
        """The command's exit status: 128 + the signal when interrupted (130 for Ctrl-C), 3 when it gave up at
        --max-attempts, 0 otherwise."""
        if self.interrupted:
            return 128 + (self.signal or 2)
        return 3 if self.gave_up else 0

    def lines(self, out: Path) -> list[str]:
        rate = self.successes / self.attempted if self.attempted else 0.0
        per_min = 60.0 * self.attempted / self.seconds if self.seconds > 0 else 0.0
        lines = [
            f"dataset: {out}",
            (
                f"episodes stored: {self.stored} (attempted {self.attempted}, success rate {rate:.1%}"
                + (f", {self.failures_dropped} failed attempts not stored)" if self.failures_dropped else ")")
            ),
            (
                f"frames: {self.frames}   speed: {per_min:.1f} episodes/min, "
                f"{self.frames / max(self.seconds, 1e-9):.0f} frames/s"
            ),
            f"size on disk: {self.size_bytes / 2**20:.1f} MiB",
        ]
        if self.physics_errors:
            lines.insert(2, f"not stored because the simulation failed: {self.physics_errors} attempt(s)")
        if self.rejected:
            lines.insert(2, f"not stored because they diverged from the source: {self.rejected} episode(s)")
        if self.interrupted:
            name = signal.Signals(self.signal or signal.SIGINT).name
            lines.insert(0, f"interrupted ({name}): every completed episode was committed; continue with --resume")
        if self.gave_up:
            lines.insert(
                0,
                f"stopped after {self.attempted} attempts ({self.successes} successes, success rate {rate:.1%}): "
                f"the attempt limit (--max-attempts) was reached with {self.stored} episode(s) stored; raise it and "
                "continue with --resume",
            )
        return lines

    def measured(self, started: float, out: Path) -> Summary:
        """This summary with the run's seconds since `started` (`time.monotonic()`) and the size of `out`."""
        self.seconds = time.monotonic() - started
        self.size_bytes = folder_size(out)
        return self

    def should_stop(self, episodes: int, limit: int) -> bool:
        """Whether a recording asked for `episodes` is done: all stored, or `limit` attempts made (it gave up)."""
        if self.stored >= episodes:
            return True
        if self.attempted >= limit:
            self.gave_up = True
            return True
        return False
