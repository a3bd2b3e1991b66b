"""Where kitbench keeps its own facts in a LeRobot dataset, readable by anything that consumes one.

`meta/kitbench_recording.json` holds the recording's settings (task, modes, policy, seed, kitbench version);
`meta/kitbench_episodes.jsonl` one line per episode (seed, success, the task's episode configuration). The
recorder writes them; replay and lerobot policies read the recording settings to know the task and the
control mode their actions mean.
"""

from __future__ import annotations

import json
from pathlib import Path

EPISODES_FILE = "meta/kitbench_episodes.jsonl"
RECORDING_FILE = "meta/kitbench_recording.json"


def read_recording_settings(root: str | Path) -> dict | None:
    """The settings kitbench recorded the dataset at `root` with, or None for a dataset it did not record."""
    path = Path(root) / RECORDING_FILE
    if not path.is_file():
        return None
    return json.loads(path.read_text())
