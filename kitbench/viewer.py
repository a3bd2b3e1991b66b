"""`kitbench view <dataset>`: a recorded episode in LeRobot's own viewer (`lerobot-dataset-viz`, on Rerun).

With a display the Rerun viewer opens; without one (a server, CI) the episode is written to a `.rrd` file to open
anywhere with `rerun <file>` (the `rerun` command comes with rerun-sdk, which `make` installs through
`lerobot[viz]`). The MCAP logs beside the dataset (`<dataset>/mcap/`) open in Foxglove.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

from kitbench.config.declare import setting
from kitbench.errors import KitbenchError
from kitbench.metadata import read_recording_settings

DEFAULT_SAVE_DIR = Path("outputs/view")


def has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


@dataclass
class ViewSettings:
    # A dataset folder (LeRobot v3).
    dataset: Path = setting(positional=True)
    # The episode's index.
    episode: int = setting(0, show_default=False)
    # Write a .rrd file into this folder instead of opening a viewer (default without a display: outputs/view).
    save: Path | None = setting(None)


def view(root: Path, episode: int = 0, save: Path | None = None) -> Path | None:
    """Show episode `episode` of the dataset at `root`, or write it to `save` (a folder; the default without a
    display is outputs/view). Returns the .rrd file written, if any."""
    from kitbench.integrity import check_dataset

    root = Path(root)
    info_path = root / "meta" / "info.json"
    if not info_path.is_file():
        raise KitbenchError(f"{root} is not a LeRobot dataset (no meta/info.json); give a dataset folder")
    check_dataset(root)
    episodes = json.loads(info_path.read_text()).get("total_episodes", 0)
    if not (isinstance(episode, int) and 0 <= episode < episodes):
        raise KitbenchError(f"episode {episode} is not in {root}: it has {episodes} (valid: 0 to {episodes - 1})")
    try:
        from lerobot.scripts.lerobot_dataset_viz import visualize_dataset
    except ImportError as exc:  # rerun-sdk missing: an install made without lerobot[viz]
        raise KitbenchError(f"viewing needs lerobot's viewer: pip install 'lerobot[viz]' ({exc})") from None
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    settings = read_recording_settings(root) or {}
    repo_id = settings.get("repo_id") or f"local/{root.name}"
    if save is None and not has_display():
        save = DEFAULT_SAVE_DIR
    dataset = LeRobotDataset(repo_id, root=root, episodes=[episode])
    # 0 loader workers: one episode is read in a blink, and lerobot's default of 4 warns on small machines
    written = visualize_dataset(
        dataset, episode_index=episode, num_workers=0, save=save is not None, output_dir=save, mode="local"
    )
    return Path(written) if written is not None else None
