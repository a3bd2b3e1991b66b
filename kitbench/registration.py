"""The task registry: `@register_env` on a task's env class makes it a kitbench task and a gymnasium env.

A task is one module under `kitbench/tasks/` (discovered on import) or anywhere else that is imported before
use: the decorator is all it takes, in the manner of ManiSkill's `@register_env("LiftPegUpright-v1",
max_episode_steps=50)`. The id and step limit live in the decorator only; the class gets them as `task_id`
and `max_episode_steps`, and gymnasium's TimeLimit enforces the limit.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, TypeVar

import gymnasium as gym

from kitbench.errors import KitbenchError

if TYPE_CHECKING:
    from kitbench.envs.interface import KitbenchEnv
    from kitbench.envs.tabletop import TabletopEnv

GYM_NAMESPACE = "kitbench"
E = TypeVar("E", bound="type[TabletopEnv]")


@dataclass(frozen=True)
class TaskEntry:
    name: str
    env_class: type[TabletopEnv]
    max_episode_steps: int

    @property
    def gym_id(self) -> str:
        return f"{GYM_NAMESPACE}/{self.name}"


TASKS: dict[str, TaskEntry] = {}


def register_env(name: str, max_episode_steps: int) -> Callable[[E], E]:
    """Class decorator: register a task env as `name` (e.g. "LiftPegUpright-v1", gym id `kitbench/<name>`)."""
    if not isinstance(max_episode_steps, int) or max_episode_steps < 1:
        raise KitbenchError(f"max_episode_steps must be a positive integer, got {max_episode_steps!r}")

    def decorate(cls: E) -> E:
        old = TASKS.get(name)
        if old is not None and (old.env_class.__module__, old.env_class.__qualname__) != (
            cls.__module__,
            cls.__qualname__,
        ):
            raise KitbenchError(
                f"task {name!r} is already registered by {old.env_class.__module__}.{old.env_class.__qualname__}"
            )
        cls.task_id = name
        cls.max_episode_steps = max_episode_steps
        entry = TaskEntry(name, cls, max_episode_steps)
        TASKS[name] = entry
        # re-registration (a module imported again) replaces the entry rather than warning
        gym.registry.pop(entry.gym_id, None)
        creator: Callable[..., gym.Env] = cls
        gym.register(id=entry.gym_id, entry_point=creator, max_episode_steps=max_episode_steps)
        return cls

    return decorate


def unregister_env(name: str) -> None:
    """Forget task `name` (for tasks defined on the fly, e.g. in a test or a notebook)."""
    entry = task_entry(name)
    del TASKS[entry.name]
    gym.registry.pop(entry.gym_id, None)


def canonical_task(name: str) -> str:
    """A task's short name, the spelling kitbench stores: its gymnasium id `kitbench/<name>` is accepted too,
    since that is how gymnasium and ManiSkill users write it. Anything else comes back unchanged."""
    prefix = f"{GYM_NAMESPACE}/"
    return name[len(prefix) :] if isinstance(name, str) and name.startswith(prefix) else name


def task_entry(name: str) -> TaskEntry:
    """The registered task `name` (or its gym id), with an error naming every registered task otherwise."""
    short = canonical_task(name)
    if not isinstance(short, str) or short not in TASKS:
        raise KitbenchError(f"unknown task {name!r}; valid choices: {', '.join(TASKS) or '(none registered)'}")
    return TASKS[short]


# `max_episode_steps` of an env without a step limit (gymnasium's spelling: no TimeLimit wrapper).
NO_STEP_LIMIT = -1


def make_env(task: str, **kwargs) -> KitbenchEnv:
    """`gymnasium.make` for a kitbench task by its short name (or gym id), with a clear error for unknown names,
    and the step limit of the chosen robot (`TabletopEnv.robot_max_episode_steps`) unless one is given
    (`NO_STEP_LIMIT`: none); as a `KitbenchEnv`, the interface the rest of kitbench uses."""
    from kitbench.envs.interface import KitbenchEnv

    entry = task_entry(task)
    if kwargs.get("max_episode_steps") is None:
        kwargs.pop("max_episode_steps", None)
        steps = entry.env_class.episode_steps(kwargs.get("robot_uids"))
        if steps != entry.max_episode_steps:
            kwargs["max_episode_steps"] = steps
    return KitbenchEnv(gym.make(entry.gym_id, **kwargs))
