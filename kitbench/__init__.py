"""kitbench: imitation-learning datasets and evaluation for tabletop manipulation on SAPIEN 3.

Importing the package registers every task in `kitbench.tasks` with gymnasium (`kitbench/<Task>-v1`). That
imports SAPIEN and the task modules (~0.55 s on the 2-core reference machine, on top of ~0.2 s for the rest);
the simulator itself starts on the first `make`.
"""

from kitbench.errors import KitbenchError
from kitbench.registration import TASKS, make_env, register_env

__version__ = "0.2.0"

import kitbench.tasks  # noqa: F401  (registers the built-in tasks; needs __version__ defined first)

__all__ = ["TASKS", "KitbenchError", "__version__", "make_env", "register_env"]
