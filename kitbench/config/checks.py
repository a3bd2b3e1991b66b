"""What a declared setting accepts: checks that refuse a value in one line naming it and what is valid.

Each check is called as `check(name, value)` (a setting's name as its flag and recipe key spell it) and raises
`KitbenchError`; `None` is only ever checked for settings whose default is `None` when a check allows it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable

from kitbench.errors import KitbenchError

Check = Callable[[str, object], None]


def is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def is_seed(value: object) -> bool:
    # gymnasium refuses negative seeds deep inside `reset`; bool is an int subclass but never meant as a seed
    return is_int(value) and value >= 0  # type: ignore[operator]


def positive_int(name: str, value: object) -> None:
    if not (is_int(value) and value >= 1):  # type: ignore[operator]
        raise KitbenchError(f"{name} must be a positive integer, got {value!r}")


def non_negative_int(name: str, value: object) -> None:
    if not (is_int(value) and value >= 0):  # type: ignore[operator]
        raise KitbenchError(f"{name} must be an integer >= 0, got {value!r}")


def seed(name: str, value: object) -> None:
    if not is_seed(value):
        raise KitbenchError(f"{name} must be a non-negative integer, got {value!r}")


def check_seed(value: object) -> None:
    """Refuse a first seed gymnasium would refuse, before anything runs."""
    seed("seed", value)


def seconds(name: str, value: object) -> None:
    # nan compares false with everything: a recording asked to commit every nan seconds would never commit
    if not (isinstance(value, int | float) and not isinstance(value, bool) and 0 <= value < math.inf):
        raise KitbenchError(f"{name} must be a finite number of seconds >= 0, got {value!r}")


def text(name: str, value: object) -> None:
    if not isinstance(value, str) or not value:
        raise KitbenchError(f"{name} must be a non-empty text, got {value!r}")


def boolean(name: str, value: object) -> None:
    if not isinstance(value, bool):
        raise KitbenchError(f"{name} must be true or false, got {value!r}")


def one_of(choices: Iterable | Callable[[], Iterable], optional: bool = False) -> Check:
    """The value must be one of `choices` (or what calling it gives: a registry filled at import); `optional`: or
    None."""

    def check(name: str, value: object) -> None:
        valid = tuple(choices() if callable(choices) else choices)
        if value in valid or (optional and value is None):
            return
        raise KitbenchError(f"unknown {name} {value!r}; valid choices: {', '.join(map(str, valid))}")

    return check


def optional(check: Check) -> Check:
    """`check`, or None (the default's meaning)."""

    def checked(name: str, value: object) -> None:
        if value is not None:
            check(name, value)

    return checked
