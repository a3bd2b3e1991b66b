"""The one exception type for mistakes a user can fix: a bad option, file, recipe, suite or checkpoint.

Its message is one line that names the bad value and the valid choices. The command line prints it and exits 2;
anything else that escapes is a bug and keeps its traceback. It subclasses ValueError, so code that already
catches ValueError around kitbench calls keeps working.
"""

from __future__ import annotations


class KitbenchError(ValueError):
    """A user-facing error: one line naming the bad value and the valid choices."""


def check_choice(kind: str, value: object, choices) -> None:
    """Refuse `value` unless it is one of `choices`, naming them all."""
    if value not in choices:
        raise KitbenchError(f"unknown {kind} {value!r}; valid choices: {', '.join(map(str, choices))}")
