"""LeRobot env plugin for kitbench: `--env.type=kitbench` for lerobot-train and lerobot-eval.

lerobot imports every installed distribution named `lerobot_env_*`; importing this one registers the env
config and the `gym_kitbench/<Task>` gym ids.
"""

import kitbench  # noqa: F401  (registers kitbench's tasks)
from lerobot_env_kitbench.config import KitbenchEnvConfig
from lerobot_env_kitbench.env import LeRobotKitbenchEnv, register_lerobot_envs

register_lerobot_envs()

__all__ = ["KitbenchEnvConfig", "LeRobotKitbenchEnv", "register_lerobot_envs"]
