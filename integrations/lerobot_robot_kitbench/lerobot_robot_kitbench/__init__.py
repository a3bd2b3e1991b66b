"""LeRobot robot plugin for kitbench: `--robot.type=kitbench_so101`, the simulated SO-101 on a kitbench task as a
LeRobot `Robot`, in the real follower's layout (`<motor>.pos`, degrees, gripper 0..100; its `front` and `wrist`
cameras), so `lerobot-teleoperate`, `lerobot-record` and `lerobot-rollout` run against the simulation unchanged.

lerobot imports every installed distribution named `lerobot_robot_*`; importing this one registers the config
(`KitbenchSO101Config`), whose device class lerobot's factory finds beside it (`KitbenchSO101`). A kitbench error
there (a bad task or setting) prints as its one line, not a traceback.
"""

import os
import sys

import kitbench  # noqa: F401  (registers kitbench's tasks)
from kitbench.errors import report_in_one_line
from lerobot_robot_kitbench.config_kitbench_so101 import KitbenchSO101Config
from lerobot_robot_kitbench.kitbench_so101 import KitbenchSO101

report_in_one_line(os.path.basename(sys.argv[0]) or "lerobot")

__all__ = ["KitbenchSO101", "KitbenchSO101Config"]
