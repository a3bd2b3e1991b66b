"""What happened to the task's object in the robot's hand over an episode: the facts failure categories use."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class GraspHistory:
    """Whether the robot ever held the task's object and whether it still holds it, updated step by step."""

    ever_grasped: bool = False
    held_at_end: bool = False

    def update(self, held: bool) -> None:
        held = bool(held)
        self.ever_grasped |= held
        self.held_at_end = held
