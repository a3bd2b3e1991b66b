"""What happened to the task's object in the robot's hand over an episode: the facts failure categories use."""

from __future__ import annotations

from dataclasses import dataclass, field

# the hand's opening (`Robot.gripper_opening`: m for fingers, rad for a jaw) grows by more than this in the step a
# grasp ends when the hand let go; a slipping object leaves it closing or still
OPENING_GROWTH = 1e-3


@dataclass
class GraspHistory:
    """Whether the robot ever held the task's object, whether it still holds it, and whether the last grasp ended
    with the hand opening (let go) rather than the object slipping out; updated step by step."""

    ever_grasped: bool = False
    held_at_end: bool = False
    released: bool = False
    _opening: float | None = field(default=None, repr=False)

    def update(self, held: bool, opening: float | None = None) -> None:
        """One step: does the hand hold the object now, and how open is it (None: not measured)."""
        held = bool(held)
        if self.held_at_end and not held:
            before = self._opening
            self.released = opening is not None and before is not None and opening - before > OPENING_GROWTH
        self.ever_grasped |= held
        self.held_at_end = held
        self._opening = opening
