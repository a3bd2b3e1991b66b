"""Stock lerobot commands as the tests run them: offline, in a process of their own (`tests.launch`), failing with
the command's output."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

from tests import launch

BIN = Path(sys.executable).parent
OFFLINE = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled"}


def lerobot_train(config: Path, data: Path, out: Path, cwd: Path, *overrides: str) -> str:
    """`lerobot-train --config_path=<config>` on the dataset at `data` into `out`, with `overrides` (`--key=value`);
    returns its output."""
    cmd = [
        str(BIN / "lerobot-train"),
        f"--config_path={config}",
        f"--dataset.root={data}",
        f"--output_dir={out}",
        "--num_workers=0",
        *overrides,
    ]
    run = launch.run(cmd, text=True, env=OFFLINE, timeout=900, cwd=cwd)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    return run.stdout + run.stderr


def small_config(root: Path, where: Path, inputs: list[str], policy: str = "act", steps: int = 2) -> Path:
    """A small ACT (or Diffusion) training config on the CPU for the dataset at `root`, reading `inputs` (stock
    ACT's and Diffusion's backbones take 3-channel images: a depth or segmentation image, or a point cloud, is
    loaded and batched with each sample but not read); written to `where`/config.json."""
    info = json.loads((root / "meta/info.json").read_text())["features"]
    features = {}
    for name in inputs:
        shape = info[name]["shape"]
        visual = info[name]["dtype"] in ("video", "image")
        features[name] = {
            "type": "VISUAL" if visual else "ENV" if name.endswith("environment_state") else "STATE",
            "shape": [shape[2], shape[0], shape[1]] if visual else shape,
        }
    if policy == "act":
        sizes = {"chunk_size": 5, "n_action_steps": 5, "dim_model": 64, "dim_feedforward": 128}
        sizes.update(n_encoder_layers=1, n_decoder_layers=1)
    else:  # a Diffusion whose 8-step horizon fits the shortest demonstration
        sizes = {"horizon": 8, "n_action_steps": 1, "down_dims": [32, 64], "num_inference_steps": 3}
        sizes.update(diffusion_step_embed_dim=32, use_group_norm=False)
    config = {
        "dataset": {"repo_id": "kitbench/test", "root": str(root)},
        "policy": {
            "type": policy,
            "device": "cpu",
            "push_to_hub": False,
            "pretrained_backbone_weights": None,
            **sizes,
            "input_features": features,
            "output_features": {"action": {"type": "ACTION", "shape": info["action"]["shape"]}},
        },
        "steps": steps,
        "batch_size": 2,
        "save_freq": steps,
        "log_freq": 1,
        "wandb": {"enable": False},
    }
    path = where / "config.json"
    path.write_text(json.dumps(config))
    return path
