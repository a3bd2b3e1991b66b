"""The task registry and its gymnasium registration (`kitbench/<Task>-v1`)."""

from __future__ import annotations

from dataclasses import dataclass

import gymnasium as gym


@dataclass(frozen=True)
class TaskEntry:
    name: str
    entry_point: str
    max_episode_steps: int

    @property
    def gym_id(self) -> str:
        return f"kitbench/{self.name}"


TASKS: dict[str, TaskEntry] = {
    t.name: t
    for t in (
        TaskEntry("LiftPegUpright-v1", "kitbench.envs.lift_peg_upright:LiftPegUprightEnv", 50),
        TaskEntry("AssemblingKits-v1", "kitbench.envs.assembling_kits:AssemblingKitsEnv", 200),
    )
}


def register_tasks() -> None:
    for task in TASKS.values():
        if task.gym_id not in gym.registry:
            gym.register(id=task.gym_id, entry_point=task.entry_point, max_episode_steps=task.max_episode_steps)


def make_env(task: str, **kwargs) -> gym.Env:
    """`gymnasium.make` for a kitbench task by its short name, with a clear error for unknown names."""
    if task not in TASKS:
        raise ValueError(f"unknown task {task!r}; valid choices: {', '.join(TASKS)}")
    return gym.make(TASKS[task].gym_id, **kwargs)
