"""Benchmark the AssemblingKits-v1 expert: `python bench/expert_assembling_kits.py [--robot panda_wristcam|so101]
[--seeds N] [--first S] [--workers K] [--control-mode M]`.

Runs seeds S..S+N-1 (default settings, `pd_joint_pos`, 200-step limit) and prints the success rate, the steps of
successful episodes (median / p90 / max), a per-shape table, failures by category and episodes per second.
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
from kitbench.kits import SHAPE_NAMES
from kitbench.planning.assembling_kits import AssemblingKitsPlanner
from kitbench.policies.joint_targets import joint_target_to_action

TASK = "kitbench/AssemblingKits-v1"


@dataclass
class Episode:
    seed: int
    shape_id: int
    success: bool
    steps: int
    category: str  # "success" or why it failed


def failure_category(planner: AssemblingKitsPlanner, info: dict) -> str:
    """The planner's own verdict if it gave up, else which success criterion was missing at the end."""
    if planner.failure is not None:
        return planner.failure
    if info["pos_correct"] and info["rot_correct"]:
        return "not inserted"
    if info["in_slot"]:
        return "seated off yaw" if not info["rot_correct"] else "seated off position"
    return f"timeout in {planner.phase}" if info["pos_diff_norm"] > 0.05 else "jammed at the slot"


def run_seeds(args: tuple[list[int], str, str]) -> list[Episode]:
    seeds, control_mode, robot = args
    env = gym.make(TASK, control_mode=control_mode, robot_uids=robot)
    episodes = []
    for seed in seeds:
        obs, info = env.reset(seed=seed)
        planner = AssemblingKitsPlanner(env)
        steps, terminated, truncated = 0, False, False
        while not (terminated or truncated):
            target = planner.act(obs)  # pd_joint_pos targets, expressed in the env's mode
            obs, _, terminated, truncated, info = env.step(joint_target_to_action(env, target[:-1], float(target[-1])))
            steps += 1
        success = bool(info["success"])
        episodes.append(
            Episode(
                seed,
                int(env.unwrapped.shape.shape_id),
                success,
                steps,
                "success" if success else failure_category(planner, info),
            )
        )
    env.close()
    return episodes


def run(n_seeds: int, workers: int, control_mode: str, robot: str = "panda_wristcam", first: int = 0) -> list[Episode]:
    seeds = list(range(first, first + n_seeds))
    if workers <= 1:
        return run_seeds((seeds, control_mode, robot))
    chunks = [(seeds[i::workers], control_mode, robot) for i in range(workers)]
    with mp.get_context("spawn").Pool(workers) as pool:
        results = pool.map(run_seeds, chunks)
    return sorted((e for chunk in results for e in chunk), key=lambda e: e.seed)


def report(episodes: list[Episode], seconds: float, control_mode: str) -> str:
    n = len(episodes)
    wins = [e for e in episodes if e.success]
    lines = [f"AssemblingKits-v1 expert ({control_mode}): {len(wins)}/{n} succeeded ({100.0 * len(wins) / n:.1f}%)"]
    if wins:
        steps = np.array([e.steps for e in wins])
        lines.append(
            f"steps over successes: median {np.median(steps):.0f}, p90 {np.percentile(steps, 90):.0f}, "
            f"max {steps.max()} (limit 200)"
        )
    lines.append("shape                 episodes  success  median steps")
    for shape_id in range(len(SHAPE_NAMES)):
        rows = [e for e in episodes if e.shape_id == shape_id]
        if not rows:
            continue
        ok = [e.steps for e in rows if e.success]
        median = f"{np.median(ok):.0f}" if ok else "-"
        rate = 100.0 * len(ok) / len(rows)
        lines.append(f"{shape_id:2d} {SHAPE_NAMES[shape_id]:<18} {len(rows):8d}  {rate:6.1f}%  {median:>12}")
    failures = collections.Counter(e.category for e in episodes if not e.success)
    if failures:
        lines.append("failures: " + ", ".join(f"{k} {v}" for k, v in failures.most_common()))
        lines.append("failed seeds: " + " ".join(f"{e.seed}({e.shape_id})" for e in episodes if not e.success))
    lines.append(f"{n / seconds:.1f} episodes/s ({seconds:.1f} s)")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", default="panda_wristcam", choices=("panda_wristcam", "so101"), help="whose expert")
    parser.add_argument("--seeds", type=int, default=500, help="run N seeds")
    parser.add_argument("--first", type=int, default=0, help="the first seed (default 0)")
    parser.add_argument("--workers", type=int, default=1, help="worker processes")
    parser.add_argument("--control-mode", default="pd_joint_pos", help="pd_joint_pos (default) or pd_joint_delta_pos")
    args = parser.parse_args()
    start = time.perf_counter()
    episodes = run(args.seeds, args.workers, args.control_mode, args.robot, args.first)
    print(report(episodes, time.perf_counter() - start, args.control_mode))


if __name__ == "__main__":
    main()
