"""Command-line flags derived from declared settings (`kitbench.config.declare`).

Every flag defaults to "not given" (None), so that what the command line says can be layered over a recipe, a
suite or a source recording (`declare.resolve`). A `bool` setting whose default is False is a switch
(`--resume`); one whose default is True gets its `--no-` form (`--mcap/--no-mcap`); a tuple of text is given
comma-separated (`--noise-phases approach,descend`) unless it repeats (`--policy-option K=V --policy-option ...`).
"""

from __future__ import annotations

import argparse
import typing
from dataclasses import MISSING
from pathlib import Path
from typing import Any

from kitbench.config.declare import Leaf, leaves


def flag_of(leaf: Leaf) -> str:
    return leaf.meta("flag") or "--" + leaf.name.replace("_", "-")


def _scalar(annotation: Any) -> Any:
    """The type argparse converts one value to."""
    if annotation in (int, float, str):
        return annotation
    if annotation is Path:
        return Path
    return str


def add_flags(
    parser: argparse.ArgumentParser, cls: type, skip: tuple[str, ...] = (), only: tuple[str, ...] | None = None
) -> None:
    """One argument per setting of `cls` that the command line may set (`only` those named, when given)."""
    for name, leaf in leaves(cls).items():
        if name in skip or not leaf.meta("cli") or (only is not None and name not in only):
            continue
        kind = leaf.base_type
        options: dict[str, Any] = {"help": leaf.help or None, "default": None}
        if leaf.meta("metavar"):
            options["metavar"] = leaf.meta("metavar")
        if leaf.meta("positional"):
            options.pop("default")
            if typing.get_origin(kind) is tuple:
                options["nargs"], kind = "+", typing.get_args(kind)[0]
            elif leaf.default is not MISSING:
                options["nargs"] = "?"
            options["type"] = str if leaf.meta("parse") else _scalar(kind)
            parser.add_argument(name, **options)
            continue
        options["dest"] = name
        if leaf.meta("required"):
            options["required"] = True
        parse = str if leaf.meta("parse") else None  # parsed in `given`, so a bad value is kitbench's one line
        if kind is bool:
            options["action"] = argparse.BooleanOptionalAction if leaf.default is True else "store_true"
        elif leaf.meta("repeat"):
            options.update(action="append", type=parse or _scalar(typing.get_args(kind)[0]))
        elif typing.get_origin(kind) is tuple:
            inner = _scalar(typing.get_args(kind)[0])
            options["type"] = parse or (lambda text, inner=inner: tuple(inner(v) for v in text.split(",")))
        else:
            options["type"] = parse or _scalar(kind)
        parser.add_argument(flag_of(leaf), **options)


def given(cls: type, args: argparse.Namespace, skip: tuple[str, ...] = ()) -> dict[str, Any]:
    """The settings of `cls` the command line gave (a repeated flag as a tuple), by name."""
    out = {}
    for name, leaf in leaves(cls).items():
        if name in skip or not hasattr(args, name):
            continue
        value = getattr(args, name)
        if value is None:
            continue
        parse = leaf.meta("parse")
        if parse is not None:
            value = [parse(v) for v in value] if isinstance(value, list) else parse(value)
        out[name] = tuple(value) if isinstance(value, list) else value
    return out
