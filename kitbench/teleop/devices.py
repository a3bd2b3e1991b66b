"""A LeRobot teleoperator by its registered type (`so101_leader`, `gamepad`, `keyboard_ee`, `phone`, any
`lerobot_teleoperator_*` plugin's), built the way lerobot-record builds one: its config class from
`TeleoperatorConfig`'s registry, the device from lerobot's factory (`make_teleoperator_from_config`), its
calibration lerobot's own. Every failure of a device (missing, unplugged, a driver not installed) is one line
naming the device and its port.
"""

from __future__ import annotations

import dataclasses
import importlib
import pkgutil
import typing
from functools import cache
from typing import Any

from kitbench.errors import KitbenchError, one_line


@cache
def load_registry() -> None:
    """Register every teleoperator lerobot ships (each subpackage registers its configs when imported, as
    lerobot-record imports them) and every installed plugin (`register_third_party_plugins`)."""
    import lerobot.teleoperators as package
    from lerobot.utils.import_utils import register_third_party_plugins

    for module in pkgutil.iter_modules(package.__path__):
        if module.ispkg:
            try:
                importlib.import_module(f"{package.__name__}.{module.name}")
            except ImportError:
                continue  # its SDK is missing: lerobot-record cannot offer it either
    register_third_party_plugins()
    # kitbench's own: the keyboard and the gamepad with the turn
    importlib.import_module("kitbench.teleop.config_keyboard")
    importlib.import_module("kitbench.teleop.config_gamepad")


def device_types() -> list[str]:
    """Every registered teleoperator type."""
    from lerobot.teleoperators import TeleoperatorConfig

    load_registry()
    return sorted(TeleoperatorConfig.get_known_choices())


def config_class(device_type: str) -> type:
    """The registered config class of `device_type`; an unknown type is one line listing the registered ones."""
    from lerobot.teleoperators import TeleoperatorConfig

    types = device_types()
    if device_type not in types:
        raise KitbenchError(f"unknown teleoperator {device_type!r}; valid choices: {', '.join(types)}")
    return TeleoperatorConfig.get_choice_class(device_type)


def option_names(cls: type) -> list[str]:
    """The options a device's config takes (its dataclass fields), required ones first."""
    fields = [f for f in dataclasses.fields(cls) if f.init]
    required = [f.name for f in fields if _required(f)]
    return required + [f.name for f in fields if not _required(f)]


def _required(field: dataclasses.Field) -> bool:
    return field.default is dataclasses.MISSING and field.default_factory is dataclasses.MISSING


def make_config(device_type: str, options: dict[str, Any], more: tuple[str, ...] = ()):
    """`device_type`'s config with `options` set (`--policy-option KEY=VALUE`, read as JSON); an unknown or
    missing option is one line listing the valid ones (the device's, then `more`: options read elsewhere)."""
    import draccus

    cls = config_class(device_type)
    names = option_names(cls)
    valid = ", ".join([*names, *more])
    for key in options:
        if key not in names:
            raise KitbenchError(f"teleop:{device_type} has no option {key!r}; valid options: {valid}")
    missing = [f.name for f in dataclasses.fields(cls) if f.init and _required(f) and f.name not in options]
    if missing:
        given = " ".join(f"--policy-option {name}=..." for name in missing)
        raise KitbenchError(f"teleop:{device_type} needs {', '.join(missing)} ({given}); valid options: {valid}")
    try:
        return draccus.decode(cls, _as_declared(cls, options))
    except draccus.utils.DecodingError as exc:
        raise KitbenchError(f"teleop:{device_type}: {one_line(exc, typed=False)}; valid options: {valid}") from None


def _as_declared(cls: type, options: dict[str, Any]) -> dict[str, Any]:
    """Options read as JSON, a number given for a text field (`id=7`) back to text."""
    hints = typing.get_type_hints(cls)
    out = dict(options)
    for key, value in options.items():
        if isinstance(value, int | float) and not isinstance(value, bool) and "str" in str(hints.get(key, "")):
            out[key] = str(value)
    return out


def port_of(config) -> str | None:
    """The port a device's config names (a leader arm's serial port), if any."""
    port = vars(config).get("port")
    return None if port is None else str(port)


def label(device_type: str, config) -> str:
    """How messages name a device: its type, and its port where it has one."""
    port = port_of(config)
    return device_type + (f" on {port}" if port else "")


def make_device(device_type: str, config):
    """The device (not connected yet), from lerobot's factory; a missing driver package is one line."""
    from lerobot.teleoperators import make_teleoperator_from_config

    try:
        return make_teleoperator_from_config(config)
    except (ImportError, ValueError, TypeError) as exc:
        raise KitbenchError(f"teleop:{label(device_type, config)}: cannot build the device: {one_line(exc)}") from None


def action_keys(device) -> list[str]:
    """The names of what a device's `get_action` returns: its `action_features`' keys, or the `names` of a
    feature dict (lerobot's gamepad and keyboard_ee declare theirs as one vector: dtype, shape, names)."""
    features = dict(device.action_features)
    names = features.get("names")
    if {"dtype", "shape"} <= set(features) and names is not None:
        return list(names)
    return list(features)
