"""Policy sources by name, as the command line spells them: `expert`, `random`, `zero`, `replay:<dataset>[:episode]`,
`lerobot:<checkpoint>`. Each policy module registers its own with `@policy_source`, as tasks register with
`@register_env`; a source defined elsewhere is registered by importing its module."""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from kitbench.errors import KitbenchError

# The modules that register kitbench's own sources, imported on the first `make_policy`.
BUILTIN_MODULES = ("expert", "baselines", "replay", "lerobot_policy", "teleop")


@dataclass(frozen=True)
class PolicySource:
    name: str
    # (what follows `name:` on the command line, or None; the device its network runs on; its options) -> policy
    make: Callable[[str | None, str, dict], Any]
    spelling: str  # how the command line writes it (`replay:<dataset>[:episode]`)
    takes_options: bool = False  # `--policy-option KEY=VALUE` sets its config's fields

    @property
    def takes_argument(self) -> bool:
        return ":" in self.spelling


SOURCES: dict[str, PolicySource] = {}


def policy_source(name: str, spelling: str | None = None, takes_options: bool = False):
    """Register the decorated factory `(argument, device, options) -> policy` as the policy source `name`."""

    def register(make: Callable[[str | None, str, dict], Any]) -> Callable[[str | None, str, dict], Any]:
        SOURCES[name] = PolicySource(name, make, spelling or name, takes_options)
        return make

    return register


def _load() -> None:
    for module in BUILTIN_MODULES:
        importlib.import_module(f"kitbench.policies.{module}")


def spellings() -> list[str]:
    """Kitbench's own sources in `BUILTIN_MODULES` order (not import order), then any others as registered."""
    _load()
    builtin = [f"kitbench.policies.{module}" for module in BUILTIN_MODULES]

    def rank(source: PolicySource) -> int:
        module = source.make.__module__
        return builtin.index(module) if module in builtin else len(builtin)

    return [source.spelling for source in sorted(SOURCES.values(), key=rank)]


def make_policy(spec: str, device: str = "cpu", options: dict | None = None):
    """The policy `spec` names (`spellings()`), its network (if any) on `device` (auto, cpu or cuda), with its
    config's `options` set for this run. Options for a policy that has no config are refused."""
    _load()
    name, colon, argument = spec.partition(":")
    source = SOURCES.get(name)
    if source is None or bool(colon) != source.takes_argument or (colon and not argument):
        raise KitbenchError(f"unknown policy {spec!r}; valid choices: {', '.join(spellings())}")
    if options and not source.takes_options:
        with_options = [s.spelling for s in SOURCES.values() if s.takes_options]
        raise KitbenchError(
            f"policy options {options} need a {' or '.join(with_options)} policy; {spec!r} has no settings"
        )
    return source.make(argument if colon else None, device, dict(options or {}))
