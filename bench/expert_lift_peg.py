"""Benchmark the LiftPegUpright-v1 expert.

    python bench/expert_lift_peg.py [--robot panda|fetch|so101] [--seeds N] [--first S] [--workers K] [--control-mode M]
                                    [--max-steps T]

Runs seeds S..S+N-1 (default settings, `pd_joint_pos` unless told, the task's 50-step limit unless `--max-steps`
raises it) with the robot's expert and prints the success rate, the steps of successful episodes
(median / p90 / max), failures by category and episodes per second.
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
from kitbench.planning.planner import PhasePlanner
from kitbench.policies.joint_targets import joint_target_to_action

TASK = "kitbench/LiftPegUpright-v1"
TASK_STEPS = 50


@dataclass
class Episode:
    seed: int
    success: bool
    steps: int
    category: str  # "success" or why it failed
    grasp_attempts: int
    tilt: float
    z_error: float


def failure_category(planner: PhasePlanner, info: dict) -> str:
    """Why an episode failed: the planner's own verdict if it gave up, else what was wrong when time ran out."""
    if planner.failure is not None:
        return planner.failure
    if planner.phase in ("approach", "descend", "insert", "grasp", "regrasp", "swing"):
        return f"timeout in {planner.phase}"
    if info["tilt"] >= 0.08:
        return "tilted"
    return "height"


def run_episode(env, planner: PhasePlanner, seed: int) -> Episode:
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


def run_seeds(args: tuple[list[int], str, str, int]) -> list[Episode]:
    seeds, control_mode, robot, max_steps = args
    env = gym.make(
        TASK, robot_uids=robot, control_mode=control_mode, obs_mode="state_dict", max_episode_steps=max_steps
    )
    planner = env.unwrapped.make_expert()
    episodes = [run_episode(env, planner, seed) for seed in seeds]
    env.close()
    return episodes


def run(
    n_seeds: int, workers: int, control_mode: str, robot: str = "panda", first: int = 0, max_steps: int = TASK_STEPS
) -> list[Episode]:
    seeds = list(range(first, first + n_seeds))
    if workers <= 1:
        return run_seeds((seeds, control_mode, robot, max_steps))
    chunks = [(seeds[i::workers], control_mode, robot, max_steps) for i in range(workers)]
    with mp.get_context("spawn").Pool(workers) as pool:
        results = pool.map(run_seeds, chunks)
    return sorted((e for chunk in results for e in chunk), key=lambda e: e.seed)


def report(
    episodes: list[Episode], seconds: float, control_mode: str, robot: str = "panda", max_steps: int = TASK_STEPS
) -> str:
    n = len(episodes)
    wins = [e for e in episodes if e.success]
    title = f"LiftPegUpright-v1 {robot} expert ({control_mode}, {max_steps}-step limit)"
    lines = [f"{title}: {len(wins)}/{n} succeeded ({100.0 * len(wins) / n:.1f}%)"]
    if max_steps != TASK_STEPS:
        within = sum(e.steps <= TASK_STEPS for e in wins)
        lines.append(f"within the task's {TASK_STEPS} steps: {within}/{n} ({100.0 * within / n:.1f}%)")
    if wins:
        steps = np.array([e.steps for e in wins])
        lines.append(
            f"steps over successes: median {np.median(steps):.0f}, p90 {np.percentile(steps, 90):.0f}, "
            f"max {steps.max()} (limit {max_steps})"
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
    parser.add_argument(
        "--robot", default="panda", choices=("panda", "fetch", "so101"), help="whose expert (default panda)"
    )
    parser.add_argument("--seeds", type=int, default=500, help="run N seeds")
    parser.add_argument("--first", type=int, default=0, help="the first seed (default 0)")
    parser.add_argument("--max-steps", type=int, default=TASK_STEPS, help="episode step limit (default the task's 50)")
    parser.add_argument("--workers", type=int, default=1, help="worker processes")
    parser.add_argument("--control-mode", default="pd_joint_pos", help="any control mode (default pd_joint_pos)")
    args = parser.parse_args()
    start = time.perf_counter()
    episodes = run(args.seeds, args.workers, args.control_mode, args.robot, args.first, args.max_steps)
    print(report(episodes, time.perf_counter() - start, args.control_mode, args.robot, args.max_steps))


if __name__ == "__main__":
    main()
