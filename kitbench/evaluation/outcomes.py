"""What a task's final state says about an episode: its success criteria and, for a failure, why it failed.

Both come from the task itself (`success_criteria`, `failure_category`), read from the env's own `evaluate()`
info at the last step, so a report scores exactly what the task scores. One category is not the task's: an
episode the simulator could not finish (`info["physics_error"]`, see `TabletopEnv.step`) failed because of
the physics, whatever its state says.
"""

from __future__ import annotations

from kitbench.envs.grasp import GraspHistory
from kitbench.envs.interface import as_kitbench

# The failure category of an episode that ended because PhysX diverged; reports list it after the task's own.
PHYSICS_ERROR = "physics_error"


def watch_grasp(env, history: GraspHistory) -> None:
    """Add one step to `history`: does the robot hold the task's object now, and how open is its hand?"""
    env = as_kitbench(env)
    history.update(env.robot.is_grasping(env.target_object), env.robot.gripper_opening())


def criteria(env, info: dict) -> dict[str, bool]:
    """The task's success criteria at one step, by name."""
    return {name: bool(info[name]) for name in as_kitbench(env).success_criteria}


def failure_category(env, info: dict, history: GraspHistory) -> str | None:
    """Why an episode that ended in `info` failed (None for a success), checked against the task's list;
    `PHYSICS_ERROR` when the simulation failed, before the task is asked."""
    if info.get("physics_error"):
        return PHYSICS_ERROR
    env = as_kitbench(env)
    category = env.failure_category(info, history)
    if category is not None and category not in env.failure_categories:
        raise RuntimeError(
            f"{env.task_id}'s failure_category returned {category!r}, which is not in its "
            f"failure_categories {env.failure_categories}"
        )
    return category
