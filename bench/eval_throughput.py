"""Evaluation throughput of `kitbench eval`: `python bench/eval_throughput.py [--task T] [--episodes N] [--no-rgb]`.

Scores the expert and the random policy on N seeds per cell, state vs rgb observations, 1 vs 2 workers, and
prints episodes/min and control steps/s of the scoring pass, with the ratios between cells, all measured in one
run. Spawned workers start inside the scoring pass (imports, the MuJoCo model, render pipelines: seconds each),
so on short suites 2 workers lose to 1; use enough episodes (hundreds) to measure scaling.
"""

from __future__ import annotations

import argparse
import tempfile

from kitbench.evaluation.runner import EvalConfig, run_eval
from kitbench.evaluation.suite import adhoc_suite


def cell(task: str, policy: str, episodes: int, obs_mode: str, workers: int) -> dict:
    with tempfile.TemporaryDirectory(prefix="kitbench-bench-") as out:
        report = run_eval(
            EvalConfig(adhoc_suite(task, episodes, obs_mode=obs_mode), policy, out, workers=workers), progress=False
        )
    timing = report["timing"]
    steps = sum(e["length"] for e in report["per_episode"])
    return {
        "eps_min": timing["episodes_per_minute"],
        "steps_s": steps / timing["scoring_seconds"],
        "success": report["success"]["rate"],
        "overhead": timing["seconds"] - timing["scoring_seconds"],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="LiftPegUpright-v1")
    parser.add_argument("--episodes", type=int, default=12, help="episodes per cell")
    parser.add_argument("--no-rgb", action="store_true", help="skip the camera cells (no Vulkan device)")
    args = parser.parse_args()
    obs_modes = ["state"] if args.no_rgb else ["state", "rgb"]
    results = {}
    print(f"{args.task}: {args.episodes} episodes per cell")
    print(f"{'policy':<7} {'obs':<6} {'workers':>7} {'episodes/min':>13} {'steps/s':>8} {'success':>8}")
    for policy in ("expert", "random"):
        for obs in obs_modes:
            for workers in (1, 2):
                r = results[policy, obs, workers] = cell(args.task, policy, args.episodes, obs, workers)
                print(
                    f"{policy:<7} {obs:<6} {workers:>7} {r['eps_min']:>13.1f} {r['steps_s']:>8.0f} "
                    f"{r['success']:>8.0%}",
                    flush=True,
                )
    for policy in ("expert", "random"):
        print(
            f"  {policy}: videos, plots and report writing after scoring: 1 worker "
            f"{results[policy, 'state', 1]['overhead']:.1f} s, "
            f"2 workers {results[policy, 'state', 2]['overhead']:.1f} s"
        )
    print("ratios (episodes/min):")
    for policy in ("expert", "random"):
        for obs in obs_modes:
            ratio = results[policy, obs, 2]["eps_min"] / results[policy, obs, 1]["eps_min"]
            print(f"  {policy} {obs}: 2 workers/1 {ratio:.2f}")
        if "rgb" in obs_modes:
            ratio = results[policy, "rgb", 1]["eps_min"] / results[policy, "state", 1]["eps_min"]
            print(f"  {policy}: rgb/state {ratio:.2f}")


if __name__ == "__main__":
    main()
