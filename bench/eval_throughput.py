"""Evaluation throughput of `kitbench eval` per executor: `python bench/eval_throughput.py [options]`.

Options: `--task T`, `--episodes N` (per cell, 40), and filters on the cells: `--policy expert,random`,
`--obs state,rgb` (`--no-rgb` when there is no Vulkan device), `--executor local,ray`, `--workers 1,2`.

Scores the policies on N seeds per cell, for every combination of the filters, and prints episodes/min (over the
wall time of `run_eval`: checking the setup, worker start-up, scoring, writing the report) and control steps/s of
the scoring pass (worker start-up included), with the ratios between cells, all measured in one run. Executors:
`local` with 1 worker is the in-process executor (`local:in-proc` in the table), with more a pool of spawned
processes (`local:pool`); `ray` is Ray actors on a local Ray instance the run starts once, as a user's runs join a
running cluster (`ray_address="auto"`; its start-up is printed on its own); each cell starts its actors. `1st ep s`
is the seconds from the call until the first score came back (checking the setup, worker start-up and one episode).
Workers start inside the scoring pass (imports, the model, render pipelines: seconds each), so on short suites 2
workers lose to 1; the default 40 episodes keep start-up from dominating, hundreds measure scaling. "Ray overhead"
is 1 - ray/local episodes/min at equal workers. A warm-up episode first pays what this process does once (importing
matplotlib for the first report; with rgb, setting up the renderer), which the first cell would otherwise pay alone.

`--journal-cost R`: only the journal's cost, measured in one run: the expert on state, local, one worker, R times
with each finished episode journaled and fsync'd (as `kitbench eval` runs) and R times with the journal's appends
skipped, alternating; prints the median episodes/s of the scoring pass of each and the difference.
"""

from __future__ import annotations

import argparse
import importlib.util
import math
import statistics
import sys
import tempfile
import time
from contextlib import contextmanager, nullcontext

from throughput import counts, executor_label, names, start_ray, timed_engine

from kitbench.evaluation import runner
from kitbench.evaluation.config import EvalConfig
from kitbench.evaluation.journal import EvalJournal
from kitbench.evaluation.runner import run_eval
from kitbench.evaluation.suite import adhoc_suite


def cell(task: str, policy: str, episodes: int, obs_mode: str, executor: str, workers: int) -> dict:
    config_executor = {"executor": executor, "ray_address": "auto"}
    with tempfile.TemporaryDirectory(prefix="kitbench-bench-") as out:
        suite = adhoc_suite(task, episodes, obs_mode=obs_mode)
        with timed_engine(runner) as arrivals:
            start = time.perf_counter()
            report = run_eval(EvalConfig.of(suite, policy, out, workers=workers, **config_executor), progress=False)
    timing = report["timing"]
    steps = sum(e["length"] for e in report["per_episode"])
    return {
        "eps_min": timing["episodes_per_minute"],
        "steps_s": steps / timing["scoring_seconds"],
        "first_s": arrivals[0] - start if arrivals else math.nan,
        "success": report["success"]["rate"],
        "overhead": timing["seconds"] - timing["scoring_seconds"],
    }


@contextmanager
def unjournaled():
    """Skip the journal's per-job append (what an evaluation cost before it had one)."""
    saved = EvalJournal.add
    EvalJournal.add = lambda self, job, results, episode=None: None  # type: ignore[method-assign]
    try:
        yield
    finally:
        EvalJournal.add = saved  # type: ignore[method-assign]


def journal_cost(task: str, episodes: int, rounds: int) -> None:
    rates: dict[str, list[float]] = {"journaled": [], "unjournaled": []}
    for _ in range(rounds):
        for name in rates:
            with tempfile.TemporaryDirectory(prefix="kitbench-bench-") as out:
                suite = adhoc_suite(task, episodes)
                with unjournaled() if name == "unjournaled" else nullcontext():
                    report = run_eval(EvalConfig.of(suite, "expert", out), progress=False)
            rates[name].append(episodes / report["timing"]["scoring_seconds"])
    medians = {name: statistics.median(r) for name, r in rates.items()}
    for name, r in rates.items():
        print(f"{name:<12} median {medians[name]:.2f} episodes/s (runs: {', '.join(f'{x:.2f}' for x in r)})")
    cost = 1 - medians["journaled"] / medians["unjournaled"]
    print(f"journaling costs {100 * cost:+.1f}% of the expert's episodes/s ({episodes} episodes, {rounds} rounds)")


def _percent(value: float) -> str:
    return "–" if math.isnan(value) else f"{100 * value:+.0f}%"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="LiftPegUpright-v1")
    parser.add_argument("--episodes", type=int, default=40, help="episodes per cell")
    parser.add_argument("--policy", type=names(("expert", "random")), default=["expert", "random"])
    parser.add_argument("--obs", type=names(("state", "rgb")), default=["state", "rgb"], help="state,rgb")
    parser.add_argument("--no-rgb", action="store_true", help="skip the camera cells (no Vulkan device)")
    parser.add_argument("--executor", type=names(("local", "ray")), default=None, help="local,ray (default both)")
    parser.add_argument("--workers", type=counts, default=[1, 2], help="worker counts, e.g. 1,2")
    parser.add_argument("--journal-cost", type=int, default=0, metavar="R", help="only the journal's cost, R rounds")
    args = parser.parse_args()
    if args.episodes < 1:
        parser.error("--episodes must be >= 1")
    if args.journal_cost:
        cell(args.task, "expert", 1, "state", "local", 1)  # warm-up
        journal_cost(args.task, args.episodes, args.journal_cost)
        return
    executors = args.executor or ["local", "ray"]
    if "ray" in executors and importlib.util.find_spec("ray") is None:
        hint = "" if args.executor else "; pass --executor local to skip the Ray cells"
        sys.exit(f"eval_throughput: the Ray cells need Ray: pip install 'kitbench[ray]'{hint}")
    ray_start = start_ray(max(args.workers)) if "ray" in executors else None
    obs_modes = ["state"] if args.no_rgb else args.obs
    policies, workers_list = args.policy, args.workers
    # warm-up: the first report imports matplotlib, and the first rendered frame compiles pipelines
    cell(args.task, "expert", 1, "rgb" if "rgb" in obs_modes else "state", "local", 1)
    results: dict = {}
    print(
        f"{args.task}: {args.episodes} episodes per cell; local:in-proc = the in-process executor (1 worker), "
        "ray = actors on the Ray instance started once for the run; times include worker start-up"
    )
    if ray_start is not None:
        print(f"Ray instance started once for the run in {ray_start:.1f} s (not in any cell's time)")
    print(
        f"{'policy':<7} {'obs':<6} {'executor':<13} {'workers':>7} {'episodes/min':>13} {'steps/s':>8} "
        f"{'1st ep s':>9} {'success':>8} {'Ray overhead':>13}"
    )
    for policy in policies:
        for obs in obs_modes:
            for workers in workers_list:
                for executor in executors:
                    r = results[policy, obs, executor, workers] = cell(
                        args.task, policy, args.episodes, obs, executor, workers
                    )
                    local = results.get((policy, obs, "local", workers))
                    overhead = _percent(1 - r["eps_min"] / local["eps_min"]) if executor == "ray" and local else ""
                    print(
                        f"{policy:<7} {obs:<6} {executor_label(executor, workers):<13} {workers:>7} "
                        f"{r['eps_min']:>13.1f} {r['steps_s']:>8.0f} {r['first_s']:>9.1f} {r['success']:>8.0%} "
                        f"{overhead:>13}",
                        flush=True,
                    )
    obs = obs_modes[0]
    print(f"outside the scoring pass: checking the setup, writing the report and plots ({obs}):")
    for policy in policies:
        for executor in executors:
            parts = [f"{w} worker(s) {results[policy, obs, executor, w]['overhead']:.1f} s" for w in workers_list]
            print(f"  {policy}, {executor}: {', '.join(parts)}")
    print("ratios (episodes/min):")
    for policy in policies:
        for obs in obs_modes:
            for executor in executors:
                first = results[policy, obs, executor, workers_list[0]]["eps_min"]
                for w in workers_list[1:]:
                    ratio = results[policy, obs, executor, w]["eps_min"] / first
                    print(f"  {policy} {obs}, {executor}: {w} workers/{workers_list[0]} {ratio:.2f}")
            if "ray" in executors and "local" in executors:
                for w in workers_list:
                    ray, local = results[policy, obs, "ray", w], results[policy, obs, "local", w]
                    print(
                        f"  {policy} {obs}, {w} worker(s): ray/local {ray['eps_min'] / local['eps_min']:.2f} "
                        f"(Ray overhead {_percent(1 - ray['eps_min'] / local['eps_min'])}; first score after "
                        f"{ray['first_s']:.1f} s vs {local['first_s']:.1f} s)"
                    )
        if len(obs_modes) == 2:
            executor, w = executors[0], workers_list[0]
            ratio = results[policy, "rgb", executor, w]["eps_min"] / results[policy, "state", executor, w]["eps_min"]
            print(f"  {policy}: rgb/state ({executor}, {w} worker(s)) {ratio:.2f}")


if __name__ == "__main__":
    main()
