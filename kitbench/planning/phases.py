"""Phase sequencing for scripted experts: control steps grouped into named phases, each planned when it starts.

`PhaseSequencer` plays the steps of timed paths (`ik.ArmIK.plan`) phase by phase and asks for the next phase's
steps when the current ones run out, which lets an expert look at the simulated state between phases.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from kitbench.planning.ik import TimedPath
from kitbench.robots.spec import CLOSED, OPEN


@dataclass
class Step:
    """One control step of a plan: the TCP target (world, for logging), its joint targets, the gripper command
    and the name of the phase it belongs to."""

    tcp: np.ndarray
    q: np.ndarray
    gripper: float
    phase: str


def steps_from(path: TimedPath, gripper: float, phase: str) -> list[Step]:
    return [Step(p, q, float(gripper), phase) for p, q in zip(path.poses, path.qs, strict=True)]


def hold(step: Step, count: int, gripper: float | None = None, phase: str | None = None) -> list[Step]:
    """`count` copies of a step, optionally with another gripper command or phase name (waiting for drives)."""
    g = step.gripper if gripper is None else gripper
    return [Step(step.tcp, step.q, g, phase or step.phase) for _ in range(count)]


class PhaseSequencer:
    """Plays planned steps; when they run out it asks `plan_next(finished_phase)` for the next phase's steps.

    Each phase is planned when it starts, from the simulated state at that moment, so an expert closes the
    loop between phases (a grasp is checked before the lift is planned from where the object really is) while
    staying open loop, hence smooth and fast, within a phase. A plan may hold steps of several consecutive
    phases (one smooth motion through approach and descent); `phase` is the name of the step being played.
    """

    def __init__(self, plan_next: Callable[[str | None], list[Step]]):
        self._plan_next = plan_next
        self._steps: deque[Step] = deque()
        self.last: Step | None = None

    @property
    def phase(self) -> str | None:
        return None if self.last is None else self.last.phase

    def reset(self) -> None:
        self._steps, self.last = deque(), None

    def next_step(self, max_empty_plans: int = 8) -> Step:
        for _ in range(max_empty_plans):
            if self._steps:
                self.last = self._steps.popleft()
                return self.last
            self._steps = deque(self._plan_next(self.phase))
        raise RuntimeError(f"after phase {self.phase!r}: {max_empty_plans} plans in a row had no steps")


__all__ = ["CLOSED", "OPEN", "PhaseSequencer", "Step", "hold", "steps_from"]
