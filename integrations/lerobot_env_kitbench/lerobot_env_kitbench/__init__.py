"""`--env.type=kitbench` for lerobot-train and lerobot-eval."""

import gym_kitbench  # noqa: F401  (registers the gym ids in every process, async eval workers included)
from kitbench.integrations.lerobot_env import KitbenchEnvConfig

__all__ = ["KitbenchEnvConfig"]
