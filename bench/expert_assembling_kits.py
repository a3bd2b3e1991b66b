"""Benchmark the AssemblingKits-v1 expert: `python bench/expert_assembling_kits.py [--robot panda_wristcam|so101]
[--seeds N] [--first S] [--workers K] [--control-mode M] [--expert-option KEY=VALUE ...] [--misread MM,DEG ...]`.

Runs seeds S..S+N-1 (the expert's settings with any `--expert-option` replaced, `pd_joint_pos`, 200-step limit) and
prints the success rate, the steps of successful episodes (median / p90 / max), a per-shape table, failures by
category and episodes per second. The table's `one grip` is how often the shape sits in the hand at one yaw: the
share of its lifted episodes whose yaw in the hand (the shape's less the hand's, folded by the shape's symmetry and
by the hand's half turn) is within 5 degrees of the shape's commonest; a policy that reads the slot's yaw and its
own can turn such a shape to its slot without reading the shape's yaw.

`--misread MM,DEG` (repeatable) runs the seeds once per pair with the expert reading the slot wrong: its centre MM
millimetres off in a direction drawn per seed, its yaw DEG degrees off with a sign drawn per seed, the same error
all episode long, and prints one row per pair. What a policy's reading of the slot and the shape must achieve is
where these rows fall off (the expert measures the shape in its hand exactly, so the rows bound a policy from above).
"""

from __future__ import annotations

import argparse
import collections
import math
import multiprocessing as mp
import time
from dataclasses import dataclass

import gymnasium as gym
import numpy as np

import kitbench  # noqa: F401  (registers the tasks)
from kitbench.geometry import planar_yaw, quat_to_matrix
from kitbench.kits import SHAPE_NAMES, shape_geometry
from kitbench.planning.assembling_kits import AssemblingKitsPlanner
from kitbench.planning.kit_grasps import grip_period
from kitbench.policies.joint_targets import joint_target_to_action

TASK = "kitbench/AssemblingKits-v1"


@dataclass
class Episode:
    seed: int
    shape_id: int
    success: bool
    steps: int
    category: str  # "success" or why it failed
    grip: tuple[float, float] | None = None  # the shape's yaw in the hand as the lift ends, folded (`grip_yaw`)


def failure_category(planner: AssemblingKitsPlanner, info: dict) -> str:
    """The planner's own verdict if it gave up, else which success criterion was missing at the end."""
    if planner.failure is not None:
        return planner.failure
    if info["pos_correct"] and info["rot_correct"]:
        return "not inserted"
    if info["in_slot"]:
        return "seated off yaw" if not info["rot_correct"] else "seated off position"
    return f"timeout in {planner.phase}" if info["pos_diff_norm"] > 0.05 else "jammed at the slot"


def grip_yaw(env) -> tuple[float, float]:
    """(the shape's yaw less the hand's, folded by `grip_period`; that period), degrees (0 and 0 for a disc or a
    ring, which sit in the hand at every yaw alike)."""
    u = env.unwrapped
    shape_yaw = planar_yaw(quat_to_matrix(u.obj.pose.q))
    hand_yaw = planar_yaw(quat_to_matrix(u.robot.tcp_pose().q))
    period = math.degrees(grip_period(u.shape.symmetry))
    return (float(math.degrees(shape_yaw - hand_yaw) % period) if period else 0.0), period


class MisreadSlot:
    """The env as an expert that misreads its slot sees it: `goal_pos` shifted in the table's plane, `goal_rot`
    turned; everything else, the success test included, is the env's own."""

    def __init__(self, env, shift_xy: np.ndarray, turn: float):
        self._env = env
        self.goal_pos = env.goal_pos + np.array([shift_xy[0], shift_xy[1], 0.0])
        self.goal_rot = env.goal_rot + turn

    def __getattr__(self, name: str):
        return getattr(self._env, name)


def misread_of(seed: int, misread: tuple[float, float]) -> tuple[np.ndarray, float]:
    """(xy shift in m, turn in rad): MM millimetres in a direction and DEG degrees with a sign, drawn from the seed
    alone, so every pair's rows see the same directions."""
    rng = np.random.default_rng([seed, 0x6D69_7372])
    angle = rng.uniform(0.0, 2.0 * math.pi)
    sign = 1.0 if rng.random() < 0.5 else -1.0
    shift = misread[0] / 1000.0 * np.array([math.cos(angle), math.sin(angle)])
    return shift, sign * math.radians(misread[1])


def run_seeds(args: tuple[list[int], str, str, dict, tuple[float, float] | None]) -> list[Episode]:
    seeds, control_mode, robot, options, misread = args
    env = gym.make(TASK, control_mode=control_mode, robot_uids=robot)
    episodes = []
    for seed in seeds:
        obs, info = env.reset(seed=seed)
        planner: AssemblingKitsPlanner = env.unwrapped.make_expert(options)
        if misread is not None:
            planner.env = MisreadSlot(planner.env, *misread_of(seed, misread))
        steps, terminated, truncated, grip = 0, False, False, None
        while not (terminated or truncated):
            phase = planner.phase
            target = planner.act(obs)  # pd_joint_pos targets, expressed in the env's mode
            obs, _, terminated, truncated, info = env.step(joint_target_to_action(env, target[:-1], float(target[-1])))
            steps += 1
            if grip is None and phase == "lift" and planner.phase != "lift":
                grip = grip_yaw(env)
        success = bool(info["success"])
        episodes.append(
            Episode(
                seed,
                int(env.unwrapped.shape.shape_id),
                success,
                steps,
                "success" if success else failure_category(planner, info),
                grip,
            )
        )
    env.close()
    return episodes


def run(
    n_seeds: int,
    workers: int,
    control_mode: str,
    robot: str = "panda_wristcam",
    first: int = 0,
    options: dict | None = None,
    misread: tuple[float, float] | None = None,
) -> list[Episode]:
    seeds = list(range(first, first + n_seeds))
    if workers <= 1:
        return run_seeds((seeds, control_mode, robot, options or {}, misread))
    chunks = [(seeds[i::workers], control_mode, robot, options or {}, misread) for i in range(workers)]
    with mp.get_context("spawn").Pool(workers) as pool:
        results = pool.map(run_seeds, chunks)
    return sorted((e for chunk in results for e in chunk), key=lambda e: e.seed)


def one_grip(rows) -> tuple[int, int]:
    """(k, n): of a shape's n lifted episodes, the k within 5 degrees of the commonest yaw in the hand."""
    grips = [e.grip for e in rows if e.grip is not None]
    if not grips or not grips[0][1]:
        return len(grips), len(grips)
    period = grips[0][1]
    yaw = np.array([g for g, _ in grips])
    apart = np.abs(yaw[:, None] - yaw[None, :]) % period
    near = (np.minimum(apart, period - apart) <= 5.0).sum(axis=1)
    return int(near.max()), len(grips)


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
    lines.append("shape                 episodes  success  median steps  one grip")
    held = lifted = 0
    for shape_id in range(len(SHAPE_NAMES)):
        rows = [e for e in episodes if e.shape_id == shape_id]
        if not rows:
            continue
        ok = [e.steps for e in rows if e.success]
        median = f"{np.median(ok):.0f}" if ok else "-"
        rate = 100.0 * len(ok) / len(rows)
        held_k, lifted_n = one_grip(rows)
        row = f"{shape_id:2d} {SHAPE_NAMES[shape_id]:<18} {len(rows):8d}  {rate:6.1f}%  {median:>12}"
        lines.append(f"{row}  {held_k:4d}/{lifted_n}")
        held, lifted = held + held_k, lifted + lifted_n
    if lifted:
        share = 100.0 * held / lifted
        lines.append(f"one grip: {held}/{lifted} lifted shapes ({share:.1f}%) within 5 deg of their shape's commonest")
    failures = collections.Counter(e.category for e in episodes if not e.success)
    if failures:
        lines.append("failures: " + ", ".join(f"{k} {v}" for k, v in failures.most_common()))
        lines.append("failed seeds: " + " ".join(f"{e.seed}({e.shape_id})" for e in episodes if not e.success))
    lines.append(f"{n / seconds:.1f} episodes/s ({seconds:.1f} s)")
    return "\n".join(lines)


def misread_report(rows: list[tuple[tuple[float, float], list[Episode]]], control_mode: str) -> str:
    """One line per misread pair: successes with their 95% interval, the shapes that need a turn apart, failures."""
    from kitbench.evaluation.stats import wilson_interval

    lines = [
        f"AssemblingKits-v1 expert ({control_mode}) reading its slot wrong, the same seeds each row",
        "slot off (mm, deg)  success              95% interval   turned shapes  failures",
    ]
    for (mm, deg), episodes in rows:
        n, k = len(episodes), sum(e.success for e in episodes)
        low, high = wilson_interval(k, n)
        turned = [e for e in episodes if shape_geometry(e.shape_id).symmetry > 0]  # not a disc or ring: yaw matters
        turned_k = sum(e.success for e in turned)
        failures = collections.Counter(e.category for e in episodes if not e.success)
        named = ", ".join(f"{c} {v}" for c, v in failures.most_common()) or "-"
        lines.append(
            f"{mm:6.2f} {deg:5.2f}       {k:4d}/{n:<4d} {100.0 * k / n:5.1f}%  "
            f"{100 * low:5.1f}-{100 * high:5.1f}%  {turned_k:4d}/{len(turned):<4d}     {named}"
        )
    return "\n".join(lines)


def parse_misread(text: str) -> tuple[float, float]:
    try:
        mm, deg = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--misread wants MM,DEG (e.g. 1.5,2), got {text!r}") from None
    if not (mm >= 0.0 and deg >= 0.0):
        raise argparse.ArgumentTypeError(f"--misread wants MM,DEG both >= 0, got {text!r}")
    return mm, deg


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", default="panda_wristcam", choices=("panda_wristcam", "so101"), help="whose expert")
    parser.add_argument("--seeds", type=int, default=500, help="run N seeds")
    parser.add_argument("--first", type=int, default=0, help="the first seed (default 0)")
    parser.add_argument("--workers", type=int, default=1, help="worker processes")
    parser.add_argument("--control-mode", default="pd_joint_pos", help="pd_joint_pos (default) or pd_joint_delta_pos")
    parser.add_argument(
        "--expert-option", action="append", default=[], metavar="KEY=VALUE", help="an expert config field, repeatable"
    )
    parser.add_argument(
        "--misread",
        action="append",
        default=[],
        type=parse_misread,
        metavar="MM,DEG",
        help="run once per pair with the slot read MM mm and DEG degrees off (repeatable)",
    )
    args = parser.parse_args()
    from kitbench.policies.lerobot_policy import parse_option

    options = dict(map(parse_option, args.expert_option))
    start = time.perf_counter()
    if args.misread:
        rows = [
            (m, run(args.seeds, args.workers, args.control_mode, args.robot, args.first, options, m))
            for m in args.misread
        ]
        print(misread_report(rows, args.control_mode))
        print(f"{time.perf_counter() - start:.1f} s")
        return
    episodes = run(args.seeds, args.workers, args.control_mode, args.robot, args.first, options)
    print(report(episodes, time.perf_counter() - start, args.control_mode))


if __name__ == "__main__":
    main()
