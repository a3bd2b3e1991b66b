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


def one_line(exc: BaseException, typed: bool = True) -> str:
    """An exception as one line: its type and its message's first line (`typed=False`: the line alone), or its type
    alone when the message is empty."""
    lines = str(exc).strip().splitlines()
    if not lines:
        return type(exc).__name__
    return f"{type(exc).__name__}: {lines[0]}" if typed else lines[0]


def report_in_one_line(program: str) -> None:
    """Have an uncaught `KitbenchError` print as the one line it is (`<program>: error: ...`) instead of a traceback,
    in a program kitbench does not run itself (lerobot-train and lerobot-eval, through the plugin); the process
    still exits 1. Anything else keeps its traceback."""
    import sys

    previous = sys.excepthook

    def hook(kind, value, traceback) -> None:
        cause = value
        while cause is not None and not isinstance(cause, KitbenchError):  # draccus wraps a config's own errors
            cause = cause.__cause__ or cause.__context__
        if cause is not None:
            print(f"{program}: error: {cause}", file=sys.stderr)
        else:
            previous(kind, value, traceback)

    sys.excepthook = hook


def check_vector(name: str, value: object, size: int):
    """`value` as a float64 vector of `size` finite numbers, or one line saying what is wrong with it."""
    import numpy as np

    try:
        v = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise KitbenchError(f"{name} must be {size} numbers, got {value!r}") from None
    if v.shape != (size,) or not np.isfinite(v).all():
        raise KitbenchError(f"{name} must be {size} finite numbers, got {value!r}")
    return v
