"""Baseline policies: uniform random actions and holding still."""

from __future__ import annotations

import numpy as np

from kitbench.envs.interface import as_kitbench
from kitbench.policies.joint_targets import joint_target_to_action
from kitbench.policies.registry import policy_source
from kitbench.robots.spec import OPEN


class RandomPolicy:
    """Uniform samples from the action box, seeded per episode so evaluations are reproducible."""

    name = "random"
    phase = None

    def reset(self, env, seed, obs, info):
        self._space = env.action_space
        self._rng = np.random.default_rng([seed, 0x5EED])

    def act(self, obs):
        low, high = self._space.low, self._space.high
        return self._rng.uniform(low, high).astype(np.float32)


class ZeroPolicy:
    """Hold the arm where it is with the gripper open, in any control mode."""

    name = "zero"
    phase = None

    def reset(self, env, seed, obs, info):
        self._env = as_kitbench(env)

    def act(self, obs):
        controller = self._env.controller
        return joint_target_to_action(self._env, controller.joint_target, OPEN)


@policy_source("random")
def _random(argument: str | None, device: str, options: dict) -> RandomPolicy:
    return RandomPolicy()


@policy_source("zero")
def _zero(argument: str | None, device: str, options: dict) -> ZeroPolicy:
    return ZeroPolicy()
