"""What each task's final state says about an episode: its success criteria and, for a failure, why it failed.

Criteria are read from the env's own `evaluate()` info at the last step, so a report scores exactly what the
task scores. Failure categories follow the task's stages, from the earliest one that went wrong.
"""

from __future__ import annotations

from dataclasses import dataclass

from kitbench.envs.assembling_kits import POS_TOLERANCE
from kitbench.envs.lift_peg_upright import MAX_TILT, MAX_Z_ERROR

NEAR_SLOT = 0.05  # m: a shape this close to its goal was brought to the kit, whatever else went wrong


@dataclass
class GraspWatch:
    """Follows whether the robot holds the task's object, step by step."""

    ever_grasped: bool = False
    held_at_end: bool = False

    def update(self, u) -> None:
        held = bool(u.robot.is_grasping(target_object(u)))
        self.ever_grasped |= held
        self.held_at_end = held


def target_object(u):
    """The object the task is about (the peg, or the shape to insert)."""
    return u.peg if hasattr(u, "peg") else u.obj


def criteria(task: str, info: dict) -> dict[str, bool]:
    """The task's success criteria at one step, by name."""
    if task == "AssemblingKits-v1":
        return {k: bool(info[k]) for k in ("pos_correct", "rot_correct", "in_slot")}
    return {"upright": float(info["tilt"]) < MAX_TILT, "at_height": float(info["z_error"]) < MAX_Z_ERROR}


FAILURE_CATEGORIES = {
    "LiftPegUpright-v1": ("never_grasped", "dropped", "not_upright", "wrong_height"),
    "AssemblingKits-v1": ("never_grasped", "dropped", "not_transported", "misaligned", "not_inserted"),
}


def failure_category(task: str, info: dict, watch: GraspWatch) -> str | None:
    """Why an episode failed (None for a success)."""
    if info["success"]:
        return None
    met = criteria(task, info)
    if task == "AssemblingKits-v1":
        if met["pos_correct"] and met["rot_correct"]:
            return "not_inserted"  # over the slot at the right yaw, not down in it
        if float(info["pos_diff_norm"]) < NEAR_SLOT:
            return "misaligned"  # brought to the slot, off in position or yaw
        if not watch.ever_grasped:
            return "never_grasped"
        return "not_transported" if watch.held_at_end else "dropped"
    if not watch.ever_grasped:
        return "never_grasped"
    if not watch.held_at_end:
        return "dropped"
    return "not_upright" if not met["upright"] else "wrong_height"


assert POS_TOLERANCE < NEAR_SLOT
