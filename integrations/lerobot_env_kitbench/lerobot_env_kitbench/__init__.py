"""LeRobot env plugin for kitbench: `--env.type=kitbench` for lerobot-train and lerobot-eval.

lerobot imports every installed distribution named `lerobot_env_*`; importing this one registers the env
config and the `gym_kitbench/<Task>` gym ids, and has `LeRobotDataset` read kitbench recordings through
kitbench's reader (`kitbench.training.reader`: the same samples, from memory; `KITBENCH_FAST_READER=0` keeps
lerobot's own). In `lerobot-train` it also flushes denormal floats to zero (`kitbench.training.denormals`; Adam's
state decays into them and slows the CPU's optimizer step; `KITBENCH_FLUSH_DENORMALS=0` keeps them). A kitbench
error there (a damaged recording, a bad setting) prints as its one line, not a traceback.
"""

import os
import sys

import kitbench  # noqa: F401  (registers kitbench's tasks)
from kitbench.errors import report_in_one_line
from kitbench.training.denormals import install as flush_denormals
from kitbench.training.reader import install as install_reader
from lerobot_env_kitbench.config import KitbenchEnvConfig
from lerobot_env_kitbench.env import LeRobotKitbenchEnv, register_lerobot_envs

register_lerobot_envs()
report_in_one_line(os.path.basename(sys.argv[0]) or "lerobot")
install_reader()
flush_denormals()

__all__ = ["KitbenchEnvConfig", "LeRobotKitbenchEnv", "register_lerobot_envs"]
