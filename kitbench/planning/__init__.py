"""Scripted experts: shared motion machinery (`motion`) and one planner per task."""

from kitbench.planning.lift_peg_upright import LiftPegUprightPlanner, PlannerConfig

__all__ = ["LiftPegUprightPlanner", "PlannerConfig"]
