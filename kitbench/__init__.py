"""kitbench: imitation-learning datasets and evaluation for tabletop manipulation on SAPIEN 3.

Importing the package registers the tasks with gymnasium (cheaply: the simulator loads on first `make`).
"""

from kitbench.registration import TASKS, register_tasks

__version__ = "0.2.0"

register_tasks()

__all__ = ["TASKS", "__version__"]
