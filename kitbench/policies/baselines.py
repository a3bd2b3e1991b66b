"""Baseline policies: uniform random actions and holding still."""

from __future__ import annotations

import numpy as np

from kitbench.policies.convert import joint_target_to_action


class RandomPolicy:
    """Uniform samples from the action box, seeded per episode so evaluations are reproducible."""

    name = "random"
    phase = None

    def reset(self, env, seed, obs, info):
        self._space = env.unwrapped.action_space
        self._rng = np.random.default_rng([seed, 0x5EED])

    def act(self, obs):
        low, high = self._space.low, self._space.high
        return self._rng.uniform(low, high).astype(np.float32)


class ZeroPolicy:
    """Hold the arm where it is with the gripper open, in any control mode."""

    name = "zero"
    phase = None

    def reset(self, env, seed, obs, info):
        self._env = env

    def act(self, obs):
        controller = self._env.unwrapped.controller
        return joint_target_to_action(self._env, controller.joint_target, -1.0)
