"""What the recorder asks of a policy with a person behind it (`Operated`): its device connected before anything is
written and let go of at the end, hooks on each of its episodes (real-time pacing, the episode keys, the live
view), and whether its env must render (for the view)."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from kitbench.rollout import Hook


class OperatorStop(Exception):
    """Escape pressed before an episode started (while the arm was brought to its start pose): no episode."""


@runtime_checkable
class Operated(Protocol):
    @property
    def renders(self) -> bool:
        """Whether its env must render (a live view of the scene)."""

    @property
    def task_step_limit(self) -> bool:
        """Whether its episodes end at the task's step limit (False: when the person ends them, at success, or at
        its own limit)."""

    def connect(self) -> None:
        """Open the device, the keys and the view (one line naming the device when it is missing)."""

    def episode_hooks(self) -> list[Hook]:
        """The hooks of its next episode, after the recording's."""

    def disconnect(self) -> None:
        """Let go of the device, the keys and the view, and report what the recording did (clipped values,
        pacing)."""


def operated(policy: object) -> Operated | None:
    return policy if isinstance(policy, Operated) else None
