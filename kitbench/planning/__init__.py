"""Scripted experts: shared motion machinery (`motion`) and one planner per task."""

from kitbench.planning.assembling_kits import AssemblingKitsPlanner, AssemblingKitsPlannerConfig
from kitbench.planning.lift_peg_upright import LiftPegUprightPlanner, PlannerConfig

__all__ = ["AssemblingKitsPlanner", "AssemblingKitsPlannerConfig", "LiftPegUprightPlanner", "PlannerConfig"]
