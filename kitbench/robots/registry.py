"""The robot registry: a robot module registers its variants' `RobotSpec`s with `register_robot`, as a task registers
its env with `@register_env`; an env refuses a robot it does not find here, naming those it does."""

from __future__ import annotations

from kitbench.robots.spec import RobotSpec

ROBOTS: dict[str, RobotSpec] = {}


def register_robot(*specs: RobotSpec) -> None:
    """Make each spec a robot by its uid (registered again, it replaces the earlier spec)."""
    for spec in specs:
        ROBOTS[spec.uid] = spec
