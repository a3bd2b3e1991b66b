"""What a policy is to kitbench: reset at each episode, then one action per observation."""

from __future__ import annotations

from typing import Protocol

import numpy as np


class Policy(Protocol):
    name: str

    def reset(self, env, seed: int, obs, info: dict) -> None:
        """Called after `env.reset(seed=seed)` with its result."""

    def act(self, obs) -> np.ndarray:
        """The next action, in the env's control mode."""

    @property
    def phase(self) -> str | None:
        """What the policy is doing now, for logs (None if it has no notion of phases)."""
        return None
