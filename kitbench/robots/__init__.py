"""Robots kitbench tasks can use, by uid."""

from kitbench.robots.panda import ROBOTS, Panda, RobotSpec

__all__ = ["ROBOTS", "Panda", "RobotSpec"]
