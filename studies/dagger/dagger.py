"""One round of DAgger against as many demonstrations: `python studies/dagger/dagger.py [--task T] [--demos D]
[--rollouts R] [--steps S] [--suite-episodes E] [--out outputs/dagger]`.

1. D expert demonstrations from the task's state recipe (`datasets/<task>_state.toml`), and a policy trained on them
   (`policies/act_<task>_state.json`, S steps): the weak checkpoint.
2. R rollouts of that checkpoint, relabelled by the expert (`kitbench record --policy lerobot:<ckpt> --label
   expert`, seeds from 100,000, every episode kept), joined to the D demonstrations (LeRobot's `aggregate_datasets`),
   and a policy trained on the D + R episodes from scratch with the same config and steps.
3. D + R expert demonstrations, and a policy trained on them the same way.

Each checkpoint is scored on the task's suite (its first E seeds) and one row printed per policy: its data, success
k/n with the Wilson 95% interval, and the failure categories. Everything is kept under `--out`.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

from kitbench.evaluation.config import EvalConfig
from kitbench.evaluation.runner import run_eval
from kitbench.evaluation.stats import wilson_interval
from kitbench.evaluation.suite import load_suite
from kitbench.recording.recorder import RecordConfig, load_recipe, record
from kitbench.registration import task_entry

ROOT = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent
ROLLOUT_SEED = 100_000  # the rollouts' seeds, clear of the demonstrations' (from 0) and of the suites' (1,000,000)


def snake(task: str) -> str:
    return "".join("_" + c.lower() if c.isupper() else c for c in task.removesuffix("-v1")).lstrip("_")


def train(config: Path, data: Path, out: Path, steps: int) -> float:
    """lerobot-train as shipped, but for the data, the output and the steps; seconds taken."""
    cmd = [str(BIN / "lerobot-train"), f"--config_path={config}", f"--dataset.root={data}", f"--output_dir={out}"]
    cmd += [f"--steps={steps}", f"--save_freq={steps}", "--env_eval_freq=0"]
    # torch gets the core the loader's workers leave (bench/learnability.py measured why)
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled", "OMP_NUM_THREADS": "1"}
    start = time.monotonic()
    with open(out.with_suffix(".log"), "w") as log:
        status = subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT, env=env).returncode
    if status != 0:
        sys.exit(f"dagger: lerobot-train failed (exit {status}); see {out.with_suffix('.log')}")
    return time.monotonic() - start


def join(parts: list[Path], out: Path) -> None:
    from lerobot.datasets.aggregate import aggregate_datasets

    aggregate_datasets([f"kitbench/{p.name}" for p in parts], "kitbench/joined", roots=parts, aggr_root=out)


def score(task: str, checkpoint: Path, control_mode: str, episodes: int, out: Path) -> dict:
    suite = load_suite(ROOT / "eval" / "suites" / f"{snake(task)}.toml").first(episodes)
    suite = suite.with_modes(control_mode=control_mode)
    return run_eval(EvalConfig.of(suite, f"lerobot:{checkpoint}", out, overwrite=True), progress=False)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="LiftPegUpright-v1")
    parser.add_argument("--demos", type=int, default=25)
    parser.add_argument("--rollouts", type=int, default=25)
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--suite-episodes", dest="suite_episodes", type=int, default=100)
    parser.add_argument("--out", default="outputs/dagger")
    args = parser.parse_args()
    task = task_entry(args.task).name
    name = snake(task)
    recipe = load_recipe(ROOT / "datasets" / f"{name}_state.toml", episodes=1, out=Path("unused"))
    config = ROOT / "policies" / f"act_{name}_state.json"
    out = Path(args.out) / f"{name}_d{args.demos}_r{args.rollouts}_s{args.steps}"
    out.mkdir(parents=True, exist_ok=True)
    d, r = args.demos, args.rollouts

    def demos(n: int) -> Path:
        root = out / f"demos_{n}"
        record(recipe.replace(episodes=n, out=root, overwrite=True, mcap=False), progress=False)
        return root

    rows = []
    weak = out / "policy_demos"
    seconds = train(config, demos(d), weak, args.steps)
    rows.append((f"{d} demos", d, weak, seconds))
    rollouts = out / "rollouts_relabelled"
    relabel = RecordConfig.of(
        task,
        r,
        rollouts,
        seed=ROLLOUT_SEED,
        control_mode=recipe.control_mode,
        policy=f"lerobot:{weak}",
        label="expert",
        settle_steps=recipe.settle_steps,
        mcap=False,
        overwrite=True,
        workers=recipe.workers,
    )
    summary = record(relabel, progress=False)
    joined = out / "demos_plus_relabelled"
    if joined.exists():
        import shutil

        shutil.rmtree(joined)
    join([out / f"demos_{d}", rollouts], joined)
    dagger = out / "policy_dagger"
    rows.append((f"{d} demos + {r} relabelled rollouts", d + r, dagger, train(config, joined, dagger, args.steps)))
    more = out / "policy_more_demos"
    rows.append((f"{d + r} demos", d + r, more, train(config, demos(d + r), more, args.steps)))
    print(
        f"{task}: ACT ({config.name}), {args.steps} steps each; the rollouts of the {d}-demo policy succeeded "
        f"{summary.successes}/{summary.attempted}"
    )
    print(f"  {'data':<40} {'episodes':>8} {'train min':>9}  {'success':>10}  {'95% CI':>11}  failures")
    for label, episodes, checkpoint, seconds in rows:
        report = score(task, checkpoint, recipe.control_mode, args.suite_episodes, out / f"eval_{checkpoint.name}")
        k, n = report["success"]["count"], report["episodes"]
        lo, hi = wilson_interval(k, n)
        failures = ", ".join(f"{c} {v}" for c, v in report["failure_categories"].items() if v) or "-"
        print(
            f"  {label:<40} {episodes:>8} {seconds / 60:>9.1f}  {k:>4}/{n:<4} {k / n:>4.0%}  "
            f"{lo:>4.0%}-{hi:<4.0%}  {failures}"
        )


if __name__ == "__main__":
    main()
