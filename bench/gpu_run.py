"""The image configs on a GPU, in one command per plan: `python bench/gpu_run.py --plan loader|learn [options]`.

Written for the lent GPU machine (one H100 or H200, 16 cores; `../shared/gpu/README.md` says how kitbench is installed
there), where every minute counts: each plan records, trains and scores with the project's own commands, samples
the GPU's utilisation (`nvidia-smi`) while it trains, writes what it measured to `<out>/<plan>.json` after every
step (a killed run keeps its figures), and skips what an earlier run of the same plan already finished.
`--tiny` runs the same steps at a tiny scale on the CPU (2 demonstrations, 2 training steps, 2 episodes scored), which
is how the script is tested before a GPU is lent.

- `loader` (the training input before and after kitbench's reader): for each image config named in `--configs`
  (default the three ACT/Diffusion configs of the issue), its recipe is recorded with `--demos` demonstrations twice,
  rgb stored as video and as the recipe stores it; then `lerobot-train --config_path=<config>` runs `--steps` steps
  on each: "before", lerobot's own reader on video (`KITBENCH_FAST_READER=0`), and "after", kitbench's reader on the
  recipe's storage. Reported per run: samples/s over the last third of the steps (lerobot's log), data wait and update
  seconds a step, the GPU busy (mean of 1 s samples) and its memory, and the minutes the config's own step count would
  take at that rate.
- `learn` (a config trained as shipped and scored): the recipe of `--config` recorded with `--demos` demonstrations,
  `lerobot-train --config_path=<config>` with `--steps` (default the config's), then `kitbench eval` on the task's
  standard suite on the GPU (`--eval-episodes` of it).

Exit status: 2 for a bad argument, 1 when a command fails (its log's tail printed).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
LOADER_CONFIGS = ("act_lift_peg_upright_rgb", "act_assembling_kits_rgb", "diffusion_lift_peg_upright_rgb")
LOG_LINE = re.compile(r"step:(\S+) .*?updt_s:([\d.]+) data_s:([\d.]+)")


def command(name: str) -> str:
    """A console script of this environment (the lent machine installs them under /tmp/site/bin, on PATH)."""
    here = BIN / name
    return str(here) if here.exists() else (shutil.which(name) or name)


def run(cmd: list[str], log: Path, env: dict | None = None) -> float:
    """Run `cmd` with its output in `log`; its seconds, or exit 1 with the log's tail."""
    log.parent.mkdir(parents=True, exist_ok=True)
    started = time.monotonic()
    with log.open("w") as handle:
        handle.write("$ " + " ".join(cmd) + "\n")
        handle.flush()
        status = subprocess.run(
            cmd, stdout=handle, stderr=subprocess.STDOUT, env={**os.environ, **(env or {})}
        ).returncode
    if status != 0:
        tail = "\n".join(log.read_text(errors="replace").replace("\r", "\n").splitlines()[-25:])
        sys.exit(f"gpu_run: {' '.join(cmd[:3])} ... failed (exit {status}); {log}:\n{tail}")
    return time.monotonic() - started


class GpuSampler:
    """`nvidia-smi` every second in the background: utilisation (%) and memory (MiB); nothing without a GPU."""

    def __init__(self, log: Path):
        self.log = log
        self.proc: subprocess.Popen | None = None

    def __enter__(self) -> GpuSampler:
        if shutil.which("nvidia-smi"):
            query = [
                "nvidia-smi",
                "--query-gpu=utilization.gpu,memory.used",
                "--format=csv,noheader,nounits",
                "-l",
                "1",
            ]
            self.proc = subprocess.Popen(query, stdout=self.log.open("w"), stderr=subprocess.DEVNULL)
        return self

    def __exit__(self, *exc) -> None:
        if self.proc is not None:
            self.proc.send_signal(signal.SIGTERM)
            self.proc.wait(timeout=10)

    def summary(self) -> dict:
        rows = []
        if self.log.is_file():
            for line in self.log.read_text().splitlines():
                parts = [p.strip() for p in line.split(",")]
                if len(parts) == 2 and all(p.isdigit() for p in parts):
                    rows.append((int(parts[0]), int(parts[1])))
        if not rows:
            return {"gpu_busy_mean": None, "gpu_memory_max_mib": None, "samples": 0}
        return {
            "gpu_busy_mean": sum(r[0] for r in rows) / len(rows),
            "gpu_memory_max_mib": max(r[1] for r in rows),
            "samples": len(rows),
        }


def recipe_of(config: str) -> Path:
    root = json.loads((ROOT / "policies" / f"{config}.json").read_text())["dataset"]["root"]
    return ROOT / "datasets" / f"{Path(root).name}.toml"


def record(recipe: Path, demos: int, out: Path, storage: str | None, workers: int, logs: Path) -> float:
    if (out / "meta" / "kitbench_recording.json").is_file():
        return 0.0
    cmd = [command("kitbench"), "record", str(recipe), "--episodes", str(demos), "--out", str(out), "--no-mcap"]
    cmd += ["--workers", str(workers), "--overwrite"]
    if storage is not None:
        cmd += ["--rgb-storage", storage]
    return run(cmd, logs / f"record_{out.name}.log")


def train(config: str, data: Path, out: Path, args, reader: str, logs: Path, steps: int | None) -> dict:
    """lerobot-train on `data`; lerobot's rates over the last third of the steps, and the GPU's."""
    shutil.rmtree(out, ignore_errors=True)
    cmd = [command("lerobot-train"), f"--config_path={ROOT / 'policies' / f'{config}.json'}"]
    cmd += [f"--dataset.root={data}", f"--output_dir={out}", "--dataset.video_backend=pyav"]
    if steps is not None:
        cmd += [f"--steps={steps}", f"--save_freq={steps}", f"--log_freq={max(1, steps // 3)}"]
    if args.tiny:
        cmd += ["--policy.device=cpu", "--num_workers=0", "--batch_size=2"]
    env = {
        "KITBENCH_FAST_READER": "1" if reader == "kitbench" else "0",
        "HF_HUB_OFFLINE": "1",
        "WANDB_MODE": "disabled",
    }
    name = f"{config}_{out.name}"
    sampler = GpuSampler(logs / f"gpu_{name}.csv")
    with sampler:
        seconds = run(cmd, logs / f"train_{name}.log", env)
    text = (logs / f"train_{name}.log").read_text(errors="replace").replace("\r", "\n")
    lines = LOG_LINE.findall(text)
    raw = json.loads((ROOT / "policies" / f"{config}.json").read_text())
    batch = 2 if args.tiny else raw["batch_size"]
    result = {"seconds": seconds, "batch_size": batch, **sampler.summary()}
    if lines:
        _, update, data_wait = lines[-1]
        per_step = float(update) + float(data_wait)
        result.update(update_s=float(update), data_s=float(data_wait), samples_per_s=batch / per_step)
        result["minutes_for_shipped_steps"] = raw["steps"] * per_step / 60
    return result


def save(out: Path, plan: str, results: dict) -> None:
    (out / f"{plan}.json").write_text(json.dumps(results, indent=1) + "\n")


def plan_loader(args, out: Path, logs: Path, results: dict) -> None:
    demos, steps = (2, 2) if args.tiny else (args.demos, args.steps or 300)
    for config in args.configs:
        recipe = recipe_of(config)
        import tomllib

        storage = tomllib.loads(recipe.read_text()).get("record", {}).get("rgb_storage", "video")
        for pipeline, (reader, kind) in {"before": ("stock", "video"), "after": ("kitbench", storage)}.items():
            key = f"{config}/{pipeline}"
            if key in results:
                continue
            data = out / "data" / f"{recipe.stem}-{kind}"
            record(recipe, demos, data, kind, args.workers, logs)
            results[key] = {
                "reader": reader,
                "storage": kind,
                **train(config, data, out / "train" / pipeline, args, reader, logs, steps),
            }
            save(out, "loader", results)
            print(f"{key}: {json.dumps(results[key])}", flush=True)


def plan_learn(args, out: Path, logs: Path, results: dict) -> None:
    config = args.config
    demos = 2 if args.tiny else args.demos
    steps = 2 if args.tiny else args.steps
    recipe = recipe_of(config)
    data = out / "data" / f"{recipe.stem}-{demos}"
    key = f"{config}/d{demos}/s{steps or 'shipped'}"
    entry = results.setdefault(key, {})
    if "train" not in entry:
        entry["record_seconds"] = record(recipe, demos, data, None, args.workers, logs)
        entry["train"] = train(config, data, out / "train" / key.replace("/", "_"), args, "kitbench", logs, steps)
        save(out, "learn", results)
    if "eval" not in entry:
        task = "lift_peg_upright" if "lift_peg" in config else "assembling_kits"
        report = out / "eval" / key.replace("/", "_")
        cmd = [command("kitbench"), "eval", "--suite", str(ROOT / "eval" / "suites" / f"{task}.toml")]
        cmd += ["--policy", f"lerobot:{out / 'train' / key.replace('/', '_')}", "--out", str(report), "--overwrite"]
        cmd += ["--episodes", str(2 if args.tiny else args.eval_episodes)]
        cmd += ["--device", "cpu" if args.tiny else "cuda", "--workers", str(1 if args.tiny else args.workers)]
        cmd += ["--batch-size", str(1 if args.tiny else args.eval_batch)]
        seconds = run(cmd, logs / f"eval_{key.replace('/', '_')}.log")
        scored = json.loads((report / "report.json").read_text())
        entry["eval"] = {"seconds": seconds, "success": scored["success"], "failures": scored["failure_categories"]}
        save(out, "learn", results)
    print(f"{key}: {json.dumps(entry)}", flush=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plan", required=True, choices=("loader", "learn"))
    parser.add_argument("--out", default="outputs/gpu_run", help="results, logs, datasets and checkpoints")
    parser.add_argument("--configs", default=",".join(LOADER_CONFIGS), help="loader: image configs, comma-separated")
    parser.add_argument("--config", default="act_assembling_kits_rgb", help="learn: the config trained and scored")
    parser.add_argument("--demos", type=int, default=50, help="demonstrations recorded per recipe")
    parser.add_argument("--steps", type=int, help="training steps (loader: 300; learn: the config's)")
    parser.add_argument("--workers", type=int, default=max(1, (os.cpu_count() or 2) - 2), help="recording workers")
    parser.add_argument("--eval-episodes", type=int, default=200, help="learn: the suite's first N seeds")
    parser.add_argument("--eval-batch", type=int, default=10, help="learn: kitbench eval --batch-size")
    parser.add_argument("--tiny", action="store_true", help="a tiny end-to-end run on the CPU (the script's test)")
    args = parser.parse_args()
    args.configs = [c.strip() for c in args.configs.split(",") if c.strip()]
    for config in [*args.configs, args.config]:
        if not (ROOT / "policies" / f"{config}.json").is_file():
            parser.error(f"no config policies/{config}.json")
    if min(args.demos, args.workers, args.eval_episodes, args.eval_batch, args.steps or 1) < 1:
        parser.error("--demos, --steps, --workers, --eval-episodes and --eval-batch must be >= 1")
    out = Path(args.out)
    logs = out / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    done = out / f"{args.plan}.json"
    results = json.loads(done.read_text()) if done.is_file() else {}
    (plan_loader if args.plan == "loader" else plan_learn)(args, out, logs, results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
