"""Robots kitbench tasks can use, by uid: one module per robot builds its `RobotSpec`s (`spec`), and the generic
`Robot` (`robot`) builds any of them into a scene."""

from kitbench.robots import fetch, panda
from kitbench.robots.robot import Robot
from kitbench.robots.spec import RobotSpec

ROBOTS: dict[str, RobotSpec] = {spec.uid: spec for spec in (*panda.SPECS, *fetch.SPECS)}

__all__ = ["ROBOTS", "Robot", "RobotSpec"]
