"""Robots kitbench tasks can use, by uid: one module per robot builds its `RobotSpec`s (`spec`) and registers them
(`registry.register_robot`); importing this package imports every module in it, so adding a robot is adding a
file here. The generic `Robot` (`robot`) builds any of them into a scene."""

import importlib
import pkgutil

from kitbench.robots.registry import ROBOTS, register_robot
from kitbench.robots.robot import Robot
from kitbench.robots.spec import RobotSpec


def _import_all() -> None:
    for module in pkgutil.iter_modules(__path__):
        if module.name != "fetch_assets":  # a download script run by path, no robot
            importlib.import_module(f"{__name__}.{module.name}")


_import_all()

__all__ = ["ROBOTS", "Robot", "RobotSpec", "register_robot"]
