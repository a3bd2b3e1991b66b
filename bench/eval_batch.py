"""Batched evaluation of a trained policy: `python bench/eval_batch.py [--checkpoint CKPT] [options]`.

Scores one lerobot checkpoint on the same seeds with `kitbench eval --batch-size B` for each B (default 1,2,4,8),
alternating the cells over `--rounds` rounds (A B C A B C: a load spike on the shared machine hits every cell alike),
and prints episodes/s of the scoring pass (the median over rounds), its ratio to batch size 1, how many episodes
ended as they did unbatched (same outcome, failure and length) and the largest relative gap of a return from its
unbatched one.

Without `--checkpoint` it makes one: `--config` (default the shipped Diffusion state config for AssemblingKits),
trained `--train-steps` steps on `--demos` demonstrations recorded with that config's recipe. Its weights barely
matter for the speed: an untrained policy runs every episode to the step limit, the costliest case, at every batch
size alike.

Options: `--episodes N` (per cell, 16), `--workers W` (1), `--device auto|cpu|cuda`.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from kitbench.evaluation.config import EvalConfig
from kitbench.evaluation.runner import run_eval
from kitbench.evaluation.suite import adhoc_suite
from kitbench.recording.recorder import load_recipe, record

ROOT = Path(__file__).resolve().parents[1]


def make_checkpoint(config: Path, demos: int, steps: int, scratch: Path) -> Path:
    raw = json.loads(config.read_text())
    name = Path(raw["dataset"]["root"]).name
    data = scratch / name
    recipe = load_recipe(ROOT / "datasets" / f"{name}.toml", episodes=demos, out=data, workers=1)
    record(recipe.replace(mcap=False), progress=False)
    out = scratch / "train"
    run = subprocess.run(
        [
            str(Path(sys.executable).parent / "lerobot-train"),
            f"--config_path={config}",
            f"--dataset.root={data}",
            f"--output_dir={out}",
            f"--steps={steps}",
            f"--save_freq={steps}",
            "--env_eval_freq=0",
            "--num_workers=0",
            "--policy.device=cpu",
        ],
        capture_output=True,
        text=True,
        env={**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled"},
    )
    if run.returncode != 0:
        sys.exit(f"eval_batch: lerobot-train failed:\n{run.stderr[-3000:]}")
    return out


def cell(task: str, checkpoint: Path, episodes: int, batch: int, workers: int, device: str) -> dict:
    with tempfile.TemporaryDirectory(prefix="kitbench-bench-") as out:
        suite = adhoc_suite(task, episodes)
        config = EvalConfig.of(suite, f"lerobot:{checkpoint}", out, workers=workers, batch_size=batch, device=device)
        report = run_eval(config, progress=False)
    return {
        "eps_s": episodes / report["timing"]["scoring_seconds"],
        "episodes": report["per_episode"],
        "device": report["timing"]["device"],
    }


def same(a: dict, b: dict) -> bool:
    """The same outcome, failure category and length (returns differ with float rounding, and a Diffusion policy
    draws other noise in another batch)."""
    return (a["success"], a["failure"], a["length"]) == (b["success"], b["failure"], b["length"])


def return_gap(runs: list[dict], base: list[dict]) -> float:
    """The largest relative difference of an episode's return from its unbatched one."""
    return max(
        abs(a["episode_return"] - b["episode_return"]) / max(1.0, abs(b["episode_return"]))
        for a, b in zip(runs, base, strict=True)
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", type=Path)
    parser.add_argument("--config", type=Path, default=ROOT / "policies" / "diffusion_assembling_kits_state.json")
    parser.add_argument("--demos", type=int, default=4)
    parser.add_argument("--train-steps", type=int, default=20)
    parser.add_argument("--episodes", type=int, default=16)
    parser.add_argument("--batch-sizes", default="1,2,4,8")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--device", default="auto")
    args = parser.parse_args()
    sizes = [int(s) for s in args.batch_sizes.split(",")]
    if 1 not in sizes:
        sizes.insert(0, 1)
    task = json.loads(args.config.read_text())["env"]["task"]
    with tempfile.TemporaryDirectory(prefix="kitbench-eval-batch-") as scratch:
        checkpoint = args.checkpoint or make_checkpoint(args.config, args.demos, args.train_steps, Path(scratch))
        if args.checkpoint is not None:
            train = json.loads((checkpoint / "pretrained_model" / "train_config.json").read_text())
            task = train["env"]["task"]
        cell(task, checkpoint, 1, 1, 1, args.device)  # warm-up: imports and the first report's matplotlib
        rates: dict[int, list[float]] = {b: [] for b in sizes}
        runs: dict[int, list] = {}
        device = "?"
        for _ in range(args.rounds):
            for b in sizes:
                result = cell(task, checkpoint, args.episodes, b, args.workers, args.device)
                rates[b].append(result["eps_s"])
                runs[b] = result["episodes"]
                device = result["device"]
    print(
        f"{task}: {checkpoint if args.checkpoint else args.config.name + ' (trained here)'}, {args.episodes} episodes "
        f"a cell, {args.workers} worker(s), {os.cpu_count()} CPUs, device {device}, median of {args.rounds} round(s)"
    )
    print(f"  {'batch':>5}  {'episodes/s':>10}  {'vs batch 1':>10}  {'as unbatched':>12}  {'return gap':>10}")
    base = statistics.median(rates[1])
    for b in sizes:
        rate = statistics.median(rates[b])
        agree = sum(same(x, y) for x, y in zip(runs[b], runs[1], strict=True))
        gap = return_gap(runs[b], runs[1])
        print(f"  {b:>5}  {rate:>10.3f}  {rate / base:>9.2f}x  {agree:>5}/{len(runs[1]):<6}  {gap:>9.1%}")


if __name__ == "__main__":
    main()
