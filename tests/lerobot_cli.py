"""Stock lerobot commands as the tests run them: offline, in a subprocess, failing with the command's output."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

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
    run = subprocess.run(cmd, capture_output=True, text=True, env=OFFLINE, timeout=900, cwd=cwd)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    return run.stdout + run.stderr
