"""The `make demo` job: a rendered look at each task scene, written as PNG files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

from kitbench.registration import TASKS, make_env


def render_task_frames(out_dir: Path, seed: int = 0) -> list[Path]:
    """For each task: the 512x512 third-person view and every observation camera, after reset(seed)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for task in TASKS:
        env = make_env(task, obs_mode="rgb", render_mode="rgb_array")
        try:
            obs, _ = env.reset(seed=seed)
            frame = env.render()
            path = out_dir / f"{task}_render.png"
            Image.fromarray(frame).save(path)
            written.append(path)
            for camera, data in obs["sensor_data"].items():
                path = out_dir / f"{task}_{camera}.png"
                Image.fromarray(np.ascontiguousarray(data["rgb"])).save(path)
                written.append(path)
        finally:
            env.close()
    return written
