"""Environment throughput benchmark: `make bench` (or `python bench/run.py [--task T]`).

Prints, per task and robot (LiftPegUpright: Panda and Fetch), env steps/s with state observations in two control
modes, with rgb observations, reset/s, and the raw PhysX rate of the same scene (robot, table and task objects
stepped with no Python in between), all measured in one run so the ratios are meaningful on a shared machine. A
robot whose model is not on this machine (Fetch on a machine set up offline) is skipped with a line saying why.
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np

import kitbench
from kitbench.errors import one_line
from kitbench.sim.scene import SimConfig

REFERENCE = {"LiftPegUpright-v1": "289 (state, joint delta), 171 (ee delta pose), 19 (rgb)"}


def env_steps_per_second(task: str, seconds: float, **kwargs) -> float:
    env = gym.make(f"kitbench/{task}", **kwargs).unwrapped
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (256, *env.action_space.shape)).astype(np.float32)
    for i in range(5):  # warm-up (first frame compiles render pipelines)
        env.step(actions[i])
    steps, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        _, _, terminated, _, _ = env.step(actions[steps % 256])
        steps += 1
        if terminated or env.elapsed_steps >= env.max_episode_steps:
            env.reset()
    rate = steps / (time.perf_counter() - start)
    env.close()
    return rate


def resets_per_second(task: str, seconds: float, **kwargs) -> float:
    env = gym.make(f"kitbench/{task}", **kwargs).unwrapped
    n, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        env.reset(seed=n)
        n += 1
    return n / (time.perf_counter() - start)


def raw_physx_substeps_per_second(task: str, seconds: float, sleep_threshold: float = 0.0, **kwargs) -> float:
    """The scene stepped with no Python in between. With a sleep threshold the robot, at rest and undriven,
    falls asleep and PhysX skips it: that is how a "raw" rate of an idle scene is usually quoted."""
    env = gym.make(f"kitbench/{task}", sim_config=SimConfig(sleep_threshold=sleep_threshold), **kwargs).unwrapped
    env.reset(seed=0)
    scene = env.scene
    n, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        for _ in range(100):
            scene.step()
        n += 100
    return n / (time.perf_counter() - start)


def bench_task(task: str, seconds: float, rgb: bool, robot: str) -> None:
    substeps = SimConfig().substeps
    on = {"robot_uids": robot}
    raw = raw_physx_substeps_per_second(task, seconds, **on)
    raw_control = raw / substeps
    raw_sleeping = raw_physx_substeps_per_second(task, seconds, sleep_threshold=0.005, **on)
    rows = [
        ("state, pd_joint_delta_pos", env_steps_per_second(task, seconds, obs_mode="state", **on)),
        (
            "state, pd_ee_delta_pose",
            env_steps_per_second(task, seconds, obs_mode="state", control_mode="pd_ee_delta_pose", **on),
        ),
    ]
    if rgb:
        rows.append(("rgb 128x128, pd_joint_delta_pos", env_steps_per_second(task, seconds, obs_mode="rgb", **on)))
    reset_rate = resets_per_second(task, seconds, **on)
    print(
        f"{task} · {robot}  (sim {SimConfig().sim_freq} Hz, control {SimConfig().control_freq} Hz, {substeps} substeps)"
    )
    print(f"  raw PhysX: {raw:,.0f} substeps/s = {raw_control:,.0f} control steps/s")
    print(
        f"  raw PhysX, idle bodies asleep (sleep threshold 0.005): {raw_sleeping:,.0f} substeps/s = "
        f"{raw_sleeping / substeps:,.0f} control steps/s ({raw_sleeping / raw:.1f}x; a driven robot never sleeps)"
    )
    for name, rate in rows:
        print(
            f"  {name:<34} {rate:8,.0f} steps/s   env/raw = {rate / raw_control:6.1%}   "
            f"env/raw asleep = {rate / (raw_sleeping / substeps):5.1%}"
        )
    print(f"  {'reset(seed)':<34} {reset_rate:8,.0f} resets/s")
    if task in REFERENCE and robot == "panda":
        print(f"  reference framework on this machine kind: {REFERENCE[task]}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seconds", type=float, default=5.0, help="measuring time per figure")
    parser.add_argument("--task", choices=sorted(kitbench.TASKS), action="append", help="default: every task")
    parser.add_argument("--no-rgb", action="store_true", help="skip the rendering figures (no Vulkan device)")
    args = parser.parse_args()
    for task in args.task or list(kitbench.TASKS):
        for robot in kitbench.TASKS[task].env_class.supported_robots:
            missing = missing_model(task, robot)
            if missing is not None:
                print(f"{task} · {robot}: skipped, its model is not on this machine: {missing}")
                continue
            bench_task(task, args.seconds, rgb=not args.no_rgb, robot=robot)


def missing_model(task: str, robot: str) -> str | None:
    """Why an env of `task` with `robot` cannot be built here (None when it can): a robot whose model is fetched
    at set-up (Fetch, docs/robots.md) raises a one-line RuntimeError naming the command that installs it, and a
    machine set up offline has none of it."""
    try:
        gym.make(f"kitbench/{task}", robot_uids=robot).close()
    except RuntimeError as exc:
        return one_line(exc, typed=False)
    return None


if __name__ == "__main__":
    main()
