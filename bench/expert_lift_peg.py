"""Benchmark the LiftPegUpright-v1 expert.

    python bench/expert_lift_peg.py [--seeds N] [--workers K] [--control-mode M]

Runs seeds 0..N-1 (default settings, `pd_joint_pos` unless told, 50-step limit) and prints the success rate, the
steps of successful episodes (median / p90 / max), failures by category and episodes per second.
"""

from __future__ import annotations

import argparse
import collections
import multiprocessing as mp
import time
from dataclasses import dataclass

import gymnasium as gym
import numpy as np

import kitbench  # noqa: F401  (registers the tasks)
from kitbench.planning.lift_peg_upright import LiftPegUprightPlanner
from kitbench.policies.convert import joint_target_to_action

TASK = "kitbench/LiftPegUpright-v1"


@dataclass
class Episode:
    seed: int
    success: bool
    steps: int
    category: str  # "success" or why it failed
    grasp_attempts: int
    tilt: float
    z_error: float


def failure_category(planner: LiftPegUprightPlanner, info: dict) -> str:
    """Why an episode failed: the planner's own verdict if it gave up, else what was wrong when time ran out."""
    if planner.failure is not None:
        return planner.failure
    if planner.phase in ("approach", "descend", "grasp", "regrasp", "swing"):
        return f"timeout in {planner.phase}"
    if info["tilt"] >= 0.08:
        return "tilted"
    return "height"


def run_episode(env, planner: LiftPegUprightPlanner, seed: int) -> Episode:
    obs, info = env.reset(seed=seed)
    planner.reset(obs, info)
    steps = 0
    terminated = truncated = False
    while not (terminated or truncated):
        target = planner.act(obs)
        obs, _, terminated, truncated, info = env.step(joint_target_to_action(env, target[:-1], float(target[-1])))
        steps += 1
    success = bool(info["success"])
    category = "success" if success else failure_category(planner, info)
    return Episode(seed, success, steps, category, planner.grasp_attempts, float(info["tilt"]), float(info["z_error"]))


def run_seeds(args: tuple[list[int], str]) -> list[Episode]:
    seeds, control_mode = args
    env = gym.make(TASK, control_mode=control_mode, obs_mode="state_dict")
    planner = LiftPegUprightPlanner(env)
    episodes = [run_episode(env, planner, seed) for seed in seeds]
    env.close()
    return episodes


def run(n_seeds: int, workers: int, control_mode: str) -> list[Episode]:
    seeds = list(range(n_seeds))
    if workers <= 1:
        return run_seeds((seeds, control_mode))
    chunks = [(seeds[i::workers], control_mode) for i in range(workers)]
    with mp.get_context("spawn").Pool(workers) as pool:
        results = pool.map(run_seeds, chunks)
    return sorted((e for chunk in results for e in chunk), key=lambda e: e.seed)


def report(episodes: list[Episode], seconds: float, control_mode: str) -> str:
    n = len(episodes)
    wins = [e for e in episodes if e.success]
    lines = [f"LiftPegUpright-v1 expert ({control_mode}): {len(wins)}/{n} succeeded ({100.0 * len(wins) / n:.1f}%)"]
    if wins:
        steps = np.array([e.steps for e in wins])
        lines.append(
            f"steps over successes: median {np.median(steps):.0f}, p90 {np.percentile(steps, 90):.0f}, "
            f"max {steps.max()} (limit 50)"
        )
    retried = sum(e.grasp_attempts > 1 for e in episodes)
    lines.append(f"episodes that re-grasped: {retried} ({sum(e.grasp_attempts > 1 for e in wins)} of them succeeded)")
    failures = collections.Counter(e.category for e in episodes if not e.success)
    if failures:
        lines.append("failures: " + ", ".join(f"{k} {v}" for k, v in failures.most_common()))
        lines.append("failed seeds: " + " ".join(str(e.seed) for e in episodes if not e.success))
    lines.append(f"{n / seconds:.1f} episodes/s ({seconds:.1f} s)")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=500, help="run seeds 0..N-1")
    parser.add_argument("--workers", type=int, default=1, help="worker processes")
    parser.add_argument("--control-mode", default="pd_joint_pos", help="any control mode (default pd_joint_pos)")
    args = parser.parse_args()
    start = time.perf_counter()
    episodes = run(args.seeds, args.workers, args.control_mode)
    print(report(episodes, time.perf_counter() - start, args.control_mode))


if __name__ == "__main__":
    main()
