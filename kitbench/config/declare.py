"""A setting is declared once: a field of a config dataclass, in the style of lerobot's configs. Its name is its
flag (`obs_mode` -> `--obs-mode`) and its key in recipe and suite files; its type and default are the field's; its
help is the comment above it (read as draccus reads lerobot's, so a config lerobot parses shows the same text); what
it accepts is its `check` (`kitbench.config.checks`).

A config nests groups of settings (a field whose type is itself a config dataclass: `RecordConfig.env`, `.output`,
...), while files and command lines stay flat: every setting's name is unique in its tree, and `build`, `flatten`
and `replace` translate between the two.
"""

from __future__ import annotations

import dataclasses
import inspect
import types
import typing
from collections.abc import Callable, Mapping
from dataclasses import MISSING, dataclass
from typing import Any

from kitbench.config.checks import Check
from kitbench.errors import KitbenchError


def setting(
    default: Any = MISSING,
    *,
    check: Check | None = None,
    parse: Callable[[str], Any] | None = None,
    flag: str | None = None,
    cli: bool = True,
    positional: bool = False,
    repeat: bool = False,
    metavar: str | None = None,
    show_default: bool = True,
    required: bool = False,
    default_factory: Any = MISSING,
) -> Any:
    """A declared setting (a dataclass field). `check(name, value)` refuses a bad value in one line; `parse` turns
    the command line's text into the value (default: the field's type); `flag`: its option when not `--<name>`;
    `cli=False`: settable in files and code only; `positional`: a positional argument (one or more for a tuple);
    `repeat`: the flag may be given several times, each adding one value; `show_default`: append the default to
    the help; `required`: the command line must give it."""
    metadata = {
        "check": check,
        "parse": parse,
        "flag": flag,
        "cli": cli,
        "positional": positional,
        "repeat": repeat,
        "metavar": metavar,
        "show_default": show_default,
        "required": required,
    }
    if default_factory is not MISSING:
        return dataclasses.field(default_factory=default_factory, metadata=metadata)
    return dataclasses.field(default=default, metadata=metadata)


@dataclass(frozen=True)
class Leaf:
    """One setting of a config tree: where it lives and how it is declared."""

    name: str
    path: tuple[str, ...]  # attribute names from the root config down to the setting
    owner: type  # the class whose body declares it (its comment is there)
    field: dataclasses.Field
    annotation: Any  # its resolved type

    def meta(self, key: str) -> Any:
        return self.field.metadata.get(key)

    @property
    def default(self) -> Any:
        if self.field.default is not MISSING:
            return self.field.default
        if self.field.default_factory is not MISSING:
            return self.field.default_factory()
        return MISSING

    @property
    def base_type(self) -> Any:
        """The annotation without `| None`."""
        args = typing.get_args(self.annotation)
        if isinstance(self.annotation, types.UnionType) or typing.get_origin(self.annotation) is typing.Union:
            rest = [a for a in args if a is not type(None)]
            return rest[0] if len(rest) == 1 else self.annotation
        return self.annotation

    @property
    def help(self) -> str:
        from draccus.wrappers.docstring import get_attribute_docstring, get_preferred_help_text

        text = get_preferred_help_text(get_attribute_docstring(self.owner, self.name), "inline") or ""
        text = " ".join(text.split())
        default = self.default
        shown = default is not MISSING and default is not None and default is not False and default != ()
        if self.meta("show_default") is not False and shown:
            end = "." if text.endswith(".") else ""
            text = f"{text.removesuffix('.')} (default {default}){end}"
        return text

    def check(self, value: Any) -> None:
        check = self.meta("check")
        if check is not None:
            check(self.name, value)


def is_config(annotation: Any) -> bool:
    return isinstance(annotation, type) and dataclasses.is_dataclass(annotation)


_LEAVES: dict[type, dict[str, Leaf]] = {}


def leaves(cls: type) -> dict[str, Leaf]:
    """Every setting of the config tree rooted at `cls`, by name."""
    if cls not in _LEAVES:
        _LEAVES[cls] = _walk(cls)
    return _LEAVES[cls]


def _walk(cls: type) -> dict[str, Leaf]:
    found: dict[str, Leaf] = {}

    def walk(owner: type, path: tuple[str, ...]) -> None:
        hints = typing.get_type_hints(owner)
        for f in dataclasses.fields(owner):
            annotation = hints[f.name]
            if is_config(annotation):
                walk(annotation, (*path, f.name))
                continue
            if f.name in found:
                raise TypeError(f"setting {f.name!r} is declared twice in {cls.__name__}")
            declared_in = next(c for c in owner.__mro__ if f.name in inspect.get_annotations(c))
            found[f.name] = Leaf(f.name, (*path, f.name), declared_in, f, annotation)

    walk(cls, ())
    return found


def groups(cls: type) -> dict[str, type]:
    """The config's direct sub-configs by field name."""
    hints = typing.get_type_hints(cls)
    return {f.name: hints[f.name] for f in dataclasses.fields(cls) if is_config(hints[f.name])}


def build(cls: type, values: Mapping[str, Any], where: str = "") -> Any:
    """An instance of `cls` from flat `values` (setting name -> value; missing ones take their defaults). An unknown
    name is refused, naming the valid ones."""
    known = leaves(cls)
    unknown = sorted(set(values) - set(known))
    if unknown:
        raise KitbenchError(f"{where}unknown setting(s) {', '.join(unknown)}; valid ones: {', '.join(known)}")

    def make(owner: type, path: tuple[str, ...]) -> Any:
        kwargs = {}
        for name, sub in groups(owner).items():
            kwargs[name] = make(sub, (*path, name))
        for leaf in known.values():
            if leaf.path[:-1] == path and leaf.name in values:
                kwargs[leaf.name] = values[leaf.name]
        return owner(**kwargs)

    return make(cls, ())


def get(obj: Any, name: str) -> Any:
    value = obj
    for part in leaves(type(obj))[name].path:
        value = getattr(value, part)
    return value


def flatten(obj: Any) -> dict[str, Any]:
    """Every setting's value, by name."""
    return {name: get(obj, name) for name in leaves(type(obj))}


def replace(obj: Any, **values: Any) -> Any:
    """A copy of `obj` with the named settings changed, wherever in the tree they live."""
    known = leaves(type(obj))
    unknown = sorted(set(values) - set(known))
    if unknown:
        raise KitbenchError(f"unknown setting(s) {', '.join(unknown)}; valid ones: {', '.join(known)}")

    def swap(node: Any, path: tuple[str, ...]) -> Any:
        here = {n: v for n, v in values.items() if known[n].path[:-1] == path}
        for name in groups(type(node)):
            if any(known[n].path[: len(path) + 1] == (*path, name) for n in values):
                here[name] = swap(getattr(node, name), (*path, name))
        return dataclasses.replace(node, **here) if here else node

    return swap(obj, ())


def validate(obj: Any, skip: tuple[str, ...] = ()) -> None:
    """Each setting's own check, in declaration order; the first bad one is raised."""
    for name, leaf in leaves(type(obj)).items():
        if name not in skip:
            leaf.check(get(obj, name))


@dataclass(frozen=True)
class Resolved:
    """Settings resolved from layers (defaults, a file, the command line), and where each value came from."""

    values: dict[str, Any]
    origins: dict[str, str]

    def asked_on(self, name: str, origin: str) -> bool:
        return self.origins.get(name) == origin


def resolve(*layers: tuple[str, Mapping[str, Any]]) -> Resolved:
    """Later layers win; a `None` in a layer means "not given there" (the command line's unset flags)."""
    values: dict[str, Any] = {}
    origins: dict[str, str] = {}
    for origin, layer in layers:
        for name, value in layer.items():
            if value is not None:
                values[name] = value
                origins[name] = origin
    return Resolved(values, origins)
