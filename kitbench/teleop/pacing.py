"""Real time while a person drives: the control loop is released once a control period on wall-clock deadlines,
so the simulation steps at the task's control rate (`Pacer`), and the intervals it kept are measured
(`Intervals`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np


@dataclass
class Intervals:
    """Step-to-step intervals (seconds) against the control period."""

    period: float
    seconds: list[float] = field(default_factory=list)
    late: int = 0  # releases more than a period behind their deadline (the schedule started afresh there)

    def stats(self) -> dict[str, float]:
        """Median, p99 and max interval (seconds), and the p99's excess over the period (a fraction)."""
        if not self.seconds:
            return {"median": float("nan"), "p99": float("nan"), "max": float("nan"), "p99_over": float("nan")}
        values = np.asarray(self.seconds)
        p99 = float(np.percentile(values, 99))
        return {
            "median": float(np.median(values)),
            "p99": p99,
            "max": float(values.max()),
            "p99_over": p99 / self.period - 1.0,
        }

    def line(self) -> str:
        if not self.seconds:
            return "no paced steps"
        s = self.stats()
        ms = {k: 1e3 * v for k, v in s.items() if k != "p99_over"}
        return (
            f"{len(self.seconds) + 1} paced steps at {1 / self.period:g} Hz: interval median {ms['median']:.1f} ms, "
            f"p99 {ms['p99']:.1f} ms, max {ms['max']:.1f} ms (period {1e3 * self.period:.1f} ms), {self.late} late"
        )


def _precise_sleep(seconds: float) -> None:
    from lerobot.utils.robot_utils import precise_sleep

    precise_sleep(seconds)


class Pacer:
    """`wait()` returns once per control period: at the deadline when the loop is early, at once when it is late.
    A loop more than a period behind starts the schedule afresh instead of rushing steps to catch up (a person
    would see the arm jump). `clock` and `sleep` are the wall clock's unless a test gives its own."""

    def __init__(
        self,
        period: float,
        clock: Callable[[], float] | None = None,
        sleep: Callable[[float], None] | None = None,
    ):
        import time

        if not period > 0:
            raise ValueError(f"a control period must be positive, got {period}")
        self.clock = clock or time.perf_counter
        self.sleep = sleep or _precise_sleep
        self.intervals = Intervals(period)
        self.deadline: float | None = None
        self.last: float | None = None

    @property
    def period(self) -> float:
        return self.intervals.period

    def restart(self) -> None:
        """A new episode: its first step goes at once, and the pause before it counts as no interval."""
        self.deadline = self.last = None

    def wait(self) -> None:
        now = self.clock()
        if self.deadline is None:
            self.deadline = now
        elif now < self.deadline:
            self.sleep(self.deadline - now)
            now = self.clock()
        elif now - self.deadline > self.period:
            self.intervals.late += 1
            self.deadline = now
        if self.last is not None:
            self.intervals.seconds.append(now - self.last)
        self.last = now
        self.deadline += self.period
