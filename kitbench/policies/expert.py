"""The expert: each task's motion planner, usable as a policy in any control mode."""

from __future__ import annotations

import importlib

from kitbench.policies.convert import joint_target_to_action

PLANNERS = {
    "LiftPegUprightEnv": "kitbench.planning.lift_peg_upright:LiftPegUprightPlanner",
    "AssemblingKitsEnv": "kitbench.planning.assembling_kits:AssemblingKitsPlanner",
}


def has_expert(env) -> bool:
    return type(env.unwrapped).__name__ in PLANNERS


def planner_class(env):
    name = type(env.unwrapped).__name__
    if name not in PLANNERS:
        raise ValueError(f"no expert planner for {name}; tasks with an expert: {', '.join(PLANNERS)}")
    module, cls = PLANNERS[name].split(":")
    return getattr(importlib.import_module(module), cls)


class ExpertPolicy:
    """Runs the planner (which plans joint-position targets) and expresses each target in the env's mode."""

    name = "expert"

    def __init__(self):
        self.planner = None
        self._env = None

    def reset(self, env, seed, obs, info):
        self._env = env
        self.planner = planner_class(env)(env)
        self.planner.reset(obs, info)

    def act(self, obs):
        target = self.planner.act(obs)
        return joint_target_to_action(self._env, target[:7], float(target[7]))

    @property
    def phase(self):
        return self.planner.phase if self.planner is not None else None

    @property
    def tcp_target(self):
        return self.planner.tcp_target if self.planner is not None else None
