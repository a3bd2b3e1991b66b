"""Perturbations by name: `@register_perturbation` adds a class, `PERTURBATIONS` lists them."""

from __future__ import annotations

from typing import TypeVar

from kitbench.errors import KitbenchError
from kitbench.perturbations.base import Perturbation

PERTURBATIONS: dict[str, type[Perturbation]] = {}
P = TypeVar("P", bound=type[Perturbation])


def register_perturbation[P: type[Perturbation]](cls: P) -> P:
    if cls.name in PERTURBATIONS and PERTURBATIONS[cls.name] is not cls:
        raise KitbenchError(f"perturbation {cls.name!r} is already registered by {PERTURBATIONS[cls.name].__name__}")
    PERTURBATIONS[cls.name] = cls
    return cls


def make_perturbation(name: str, level: float) -> Perturbation:
    """The perturbation `name` at `level`, or a one-line error naming the valid names."""
    if name not in PERTURBATIONS:
        raise KitbenchError(f"unknown perturbation {name!r}; valid choices: {', '.join(PERTURBATIONS)}")
    return PERTURBATIONS[name](level)
