"""Training throughput of a shipped lerobot config on this machine: torch threads x data-loader workers.

    python bench/train_throughput.py [--config policies/act_lift_peg_upright_state.json] [--steps 300]
        [--settings 2x1,1x2,2x0] [--set policy.use_vae=false ...]
        [--resume <run>/checkpoints/<step>] [--denormals flush,keep]

Each setting `TxW` runs stock `lerobot-train` for --steps steps with OMP_NUM_THREADS=T (torch's intra-op threads) and
`--num_workers=W`, on the dataset the config names (record it first: `kitbench record datasets/<recipe>.toml`), with
no evaluation and no checkpoint. It prints, per setting, lerobot's own timings over the last third of the steps
(the first ones pay for start-up and the workers' first batches): seconds a step spends in the update and waiting
for data, steps/s, samples/s, and the ratio to the first setting, all measured in this one run, one setting after
the other. `--set key=value` passes further overrides to every run (e.g. `--set policy.use_vae=false`).

`--resume` continues a training from one of its checkpoints for --steps steps instead (its config, weights and
optimizer state: a slowdown that only shows once the optimizer state has aged, such as denormals, shows there).
`--denormals flush,keep` runs each setting with kitbench's plugin flushing denormals to zero (`flush`, what
lerobot-train does with kitbench installed) and with IEEE denormals (`keep`, `KITBENCH_FLUSH_DENORMALS=0`).

Exit status: 2 for a bad argument, 1 when a run fails (the tail of its output printed).
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
SETTING = re.compile(r"(\d+)x(\d+)")
LOG_LINE = re.compile(r"step:([\d.]+[KMB]?) .*?updt_s:([\d.]+) data_s:([\d.]+)")  # lerobot writes 3000 as 3K


def parse_settings(text: str) -> list[tuple[int, int]]:
    out = []
    for part in text.split(","):
        match = SETTING.fullmatch(part.strip())
        if not match or int(match[1]) < 1:
            raise ValueError(f"--settings {text!r}: {part!r} is not THREADSxWORKERS with THREADS >= 1, e.g. 1x2")
        out.append((int(match[1]), int(match[2])))
    return out


DENORMALS = {"flush": "1", "keep": "0"}


def parse_denormals(text: str) -> list[str]:
    modes = [part.strip() for part in text.split(",")]
    for mode in modes:
        if mode not in DENORMALS:
            raise ValueError(f"--denormals {text!r}: {mode!r} is not one of {', '.join(DENORMALS)}")
    return modes


def resume_start(checkpoint: Path) -> int:
    """The step a checkpoint was saved at; an error naming what is missing when it is not a lerobot checkpoint."""
    step_file = checkpoint / "training_state" / "training_step.json"
    if not step_file.is_file() or not (checkpoint / "pretrained_model" / "train_config.json").is_file():
        raise ValueError(
            f"--resume {checkpoint}: not a lerobot-train checkpoint (give <output_dir>/checkpoints/<step>, "
            "which holds pretrained_model/train_config.json and training_state/)"
        )
    return int(json.loads(step_file.read_text())["step"])


def run_setting(
    config: Path,
    steps: int,
    threads: int,
    workers: int,
    extra: list[str],
    denormals: str = "flush",
    start: int | None = None,
) -> dict:
    """One lerobot-train run; lerobot's timings averaged over its last log window (the last third of the steps).
    With `start`, `config` is a checkpoint's train_config.json and the run resumes it for `steps` more steps."""
    window = max(1, steps // 3)
    with tempfile.TemporaryDirectory(prefix="kitbench-train-throughput-") as tmp:
        end = steps if start is None else start + steps
        command = [
            str(BIN / "lerobot-train"),
            f"--config_path={config}",
            *([] if start is None else ["--resume=true"]),
            f"--output_dir={Path(tmp) / 'train'}",
            f"--steps={end}",
            f"--log_freq={window}",
            f"--num_workers={workers}",
            "--env_eval_freq=0",
            f"--save_freq={end + 1}",
            "--save_checkpoint=false",
            *extra,
        ]
        env = {
            **os.environ,
            "OMP_NUM_THREADS": str(threads),
            "HF_HUB_OFFLINE": "1",
            "WANDB_MODE": "disabled",
            "KITBENCH_FLUSH_DENORMALS": DENORMALS[denormals],
        }
        run = subprocess.run(command, capture_output=True, text=True, env=env, cwd=ROOT, check=False)
    output = (run.stdout + run.stderr).replace("\r", "\n")  # tqdm redraws its bar with carriage returns
    lines = list(LOG_LINE.finditer(output))
    if run.returncode != 0 or not lines:
        tail = "\n".join(output.splitlines()[-25:])
        raise RuntimeError(f"lerobot-train failed ({threads} threads, {workers} workers):\n{tail}")
    last = lines[-1]
    update, data = float(last[2]), float(last[3])
    return {"threads": threads, "workers": workers, "denormals": denormals, "update_s": update, "data_s": data}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default=str(ROOT / "policies/act_lift_peg_upright_state.json"))
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--settings", default="2x1,2x0,2x2,1x1,1x2", help="THREADSxWORKERS, comma-separated")
    parser.add_argument("--set", action="append", default=[], help="a further lerobot-train override, key=value")
    parser.add_argument("--resume", help="continue this lerobot-train checkpoint (<output_dir>/checkpoints/<step>)")
    parser.add_argument("--denormals", default="flush", help="flush, keep or both (comma-separated)")
    args = parser.parse_args()
    try:
        settings = parse_settings(args.settings)
        modes = parse_denormals(args.denormals)
        start = None if args.resume is None else resume_start(Path(args.resume))
        config = Path(args.config) if args.resume is None else Path(args.resume) / "pretrained_model/train_config.json"
        data = json.loads(config.read_text())
        if args.steps < 3:
            raise ValueError(f"--steps must be at least 3, got {args.steps}")
        for item in args.set:
            if "=" not in item:
                raise ValueError(f"--set {item!r}: give key=value, e.g. --set policy.use_vae=false")
        root = Path(data["dataset"]["root"])
        if not (ROOT / root / "meta" / "info.json").is_file() and not (root / "meta" / "info.json").is_file():
            raise ValueError(f"no dataset at {root} (the config's dataset.root): record it with its recipe first")
    except (OSError, ValueError, KeyError) as exc:
        print(f"train_throughput: error: {exc}", file=sys.stderr)
        return 2
    batch = data.get("batch_size", 8)
    extra = [f"--{item}" for item in args.set]
    name = config.name if start is None else f"{args.resume} (from step {start})"
    print(f"{name}: batch {batch}, {args.steps} steps a setting, {os.cpu_count()} cores", flush=True)
    rows = []
    try:
        for (threads, workers), mode in itertools.product(settings, modes):
            row = run_setting(config, args.steps, threads, workers, extra, mode, start)
            rows.append(row)
            step = row["update_s"] + row["data_s"]
            print(
                f"threads {threads} workers {workers} denormals {mode}: update {row['update_s'] * 1000:.0f} ms + "
                f"data wait "
                f"{row['data_s'] * 1000:.0f} ms = {1 / step:.2f} steps/s ({batch / step:.0f} samples/s), "
                f"{(rows[0]['update_s'] + rows[0]['data_s']) / step:.2f}x the first setting",
                flush=True,
            )
    except RuntimeError as exc:
        print(f"train_throughput: error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
