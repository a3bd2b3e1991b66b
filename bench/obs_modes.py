"""What each observation mode costs: `python bench/obs_modes.py [--task T[,T]] [--modes M,M,...] [--seconds S]
[--rounds R] [--episodes E] [--no-sizes]`.

Prints, per task (default: every task), measured in one run:

1. Env steps/s per obs mode (default `state,rgb,rgbd,depth,segmentation,rgb+depth+segmentation,pointcloud`;
   any of `kitbench.envs.modes.OBS_MODES`), control mode `pd_joint_delta_pos`, random actions drawn once from a
   seeded generator, resetting when an episode ends, as `bench/run.py` does. One env per mode is built up front,
   then the modes are timed S seconds each in turn (A B C A B C ...) for R rounds, so a load spike on the shared
   machine hits every mode alike instead of one. Printed: each round's rate, the median across rounds, its ratio
   to rgb and the cost vs rgb (1 - ratio: the fraction of rgb's steps/s the mode loses, negative when it is
   faster), with the targets: rgbd within 15% of rgb, pointcloud within 40% (PASS/MISS; the exit code stays 0).
   `spread` is (max - min) / median of the rounds: large means a noisy run.
2. Unless `--no-sizes`: E expert episodes (default 2) recorded per mode with `kitbench record`'s recorder
   (`pd_joint_pos`) into a temporary folder, and the same again with MCAP logs on: MiB per episode of the
   LeRobot dataset (the folder without `mcap/`, from the recording without MCAP), of the MCAP logs (`mcap/`, from
   the recording with them), and frames per episode.

The header names the machine (CPUs, platform) and the renderer (`kitbench doctor`'s Vulkan line): the rates of
the camera modes depend on it far more than on the CPU (llvmpipe renders on the CPU).
"""

from __future__ import annotations

import argparse
import gc
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
from throughput import names

import kitbench
from kitbench.doctor import check_vulkan
from kitbench.env_settings import OBS_MODES as RECORDABLE  # what a recording stores
from kitbench.envs.modes import OBS_MODES
from kitbench.errors import one_line
from kitbench.recording.recorder import MCAP_DIR, RecordConfig, record
from kitbench.recording.summary import folder_size

DEFAULT_MODES = "state,rgb,rgbd,depth,segmentation,rgb+depth+segmentation,pointcloud"
CONTROL_MODE = "pd_joint_delta_pos"
# the largest fraction of rgb's steps/s each mode may lose (docs/observations.md)
TARGETS = {"rgbd": 0.15, "pointcloud": 0.40}
WARMUP_STEPS = 5  # the first frame compiles render pipelines


class _Timed:
    """One mode's env, stepped in slices of S seconds; its action index carries across slices so every mode
    replays the same action sequence."""

    def __init__(self, task: str, mode: str, actions: np.ndarray):
        self.env = gym.make(f"kitbench/{task}", obs_mode=mode, control_mode=CONTROL_MODE).unwrapped
        self.env.reset(seed=0)
        self.actions = actions
        self.i = 0
        for _ in range(WARMUP_STEPS):
            self._step()

    def _step(self) -> None:
        env = self.env
        _, _, terminated, truncated, _ = env.step(self.actions[self.i % len(self.actions)])
        self.i += 1
        if terminated or truncated or env.elapsed_steps >= env.max_episode_steps:
            env.reset()

    def rate(self, seconds: float) -> float:
        steps, start = 0, time.perf_counter()
        while time.perf_counter() - start < seconds:
            self._step()
            steps += 1
        return steps / (time.perf_counter() - start)


def step_rates(task: str, modes: list[str], seconds: float, rounds: int) -> dict[str, list[float]]:
    """Each mode's steps/s in each round, the modes interleaved within a round."""
    probe = gym.make(f"kitbench/{task}", obs_mode="state", control_mode=CONTROL_MODE).unwrapped
    shape = probe.action_space.shape
    probe.close()
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (256, *shape)).astype(np.float32)
    timed = {mode: _Timed(task, mode, actions) for mode in modes}
    rates: dict[str, list[float]] = {mode: [] for mode in modes}
    try:
        for _ in range(rounds):
            for mode in modes:
                # the state env rebuilds its scene dozens of times a second: collect that garbage now, or the
                # next mode's slice pays for it
                gc.collect()
                rates[mode].append(timed[mode].rate(seconds))
    finally:
        for t in timed.values():
            t.env.close()
    return rates


def print_rates(task: str, rates: dict[str, list[float]], seconds: float, rounds: int) -> None:
    print(
        f"{task}: env steps/s, {CONTROL_MODE}, random actions; {rounds} round(s) of {seconds:g} s per mode, "
        "modes interleaved within each round"
    )
    rounds_header = " ".join(f"{f'round {r + 1}':>8}" for r in range(rounds))
    print(f"  {'obs mode':<24} {rounds_header} {'median':>8} {'spread':>7} {'vs rgb':>7} {'cost vs rgb':>12}  target")
    medians = {mode: statistics.median(r) for mode, r in rates.items()}
    rgb = medians.get("rgb")
    for mode, per_round in rates.items():
        median = medians[mode]
        spread = (max(per_round) - min(per_round)) / median if median > 0 else float("nan")
        ratio = median / rgb if rgb else None
        target = ""
        if ratio is not None and mode in TARGETS:
            limit = TARGETS[mode]
            target = f"within {limit:.0%} of rgb: {'PASS' if 1 - ratio <= limit else 'MISS'}"
        cells = " ".join(f"{r:>8.1f}" for r in per_round)
        print(
            f"  {mode:<24} {cells} {median:>8.1f} {spread:>7.0%} "
            f"{'–' if ratio is None else f'{ratio:.2f}':>7} {'–' if ratio is None else f'{1 - ratio:+.0%}':>12}"
            f"  {target}".rstrip(),
            flush=True,
        )
    if rgb:
        for mode, limit in TARGETS.items():
            if mode in medians:
                ratio = medians[mode] / rgb
                verdict = "PASS" if 1 - ratio <= limit else "MISS"
                print(
                    f"  {mode} / rgb = {ratio:.2f}: cost vs rgb {1 - ratio:+.0%} (target: within {limit:.0%}) {verdict}"
                )
    else:
        print("  (no rgb among the modes: no ratios or targets)")


def recording_sizes(task: str, mode: str, episodes: int, root: Path) -> dict:
    """MiB per episode of the dataset (recorded without MCAP) and of the MCAP logs (recorded again with them)."""
    folder = root / task / mode.replace("+", "_")
    result = {}
    for mcap in (False, True):
        out = folder / ("with-mcap" if mcap else "dataset")
        config = RecordConfig.of(
            task=task, episodes=episodes, out=out, obs_mode=mode, control_mode="pd_joint_pos", mcap=mcap
        )
        s = record(config, progress=False)
        stored = max(s.stored, 1)
        logs = folder_size(out / MCAP_DIR)
        if mcap:
            result["mcap_mib"] = logs / 2**20 / stored
            # the same seeds with MCAP on: the dataset part should not change
            result["dataset_mib_with_mcap"] = (folder_size(out) - logs) / 2**20 / stored
        else:
            result["dataset_mib"] = (folder_size(out) - logs) / 2**20 / stored
            result["frames"] = s.frames / stored
            result["stored"] = s.stored
    return result


def print_sizes(task: str, modes: list[str], episodes: int, root: Path) -> None:
    print(
        f"{task}: size per episode, {episodes} expert episode(s) per mode, pd_joint_pos "
        "(dataset: recorded without MCAP, the folder without mcap/; MCAP: recorded again with it, mcap/ alone)"
    )
    print(f"  {'obs mode':<24} {'episodes':>8} {'frames/ep':>10} {'dataset MiB/ep':>15} {'MCAP MiB/ep':>12}")
    for mode in modes:
        try:
            r = recording_sizes(task, mode, episodes, root)
        except Exception as exc:  # noqa: BLE001 - one mode that cannot record should not hide the others' sizes
            print(f"  {mode:<24} recording failed: {one_line(exc)}", flush=True)
            continue
        note = ""
        if abs(r["dataset_mib_with_mcap"] - r["dataset_mib"]) > 0.01 * max(r["dataset_mib"], 1e-9):
            note = f"   (dataset {r['dataset_mib_with_mcap']:.2f} MiB/ep in the recording with MCAP)"
        print(
            f"  {mode:<24} {r['stored']:>8} {r['frames']:>10.1f} {r['dataset_mib']:>15.2f} {r['mcap_mib']:>12.2f}"
            f"{note}",
            flush=True,
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--task",
        type=names(tuple(kitbench.TASKS)),
        default=list(kitbench.TASKS),
        help="comma-separated; default: every task",
    )
    parser.add_argument("--modes", type=names(OBS_MODES), default=DEFAULT_MODES.split(","), help=DEFAULT_MODES)
    parser.add_argument("--seconds", type=float, default=3.0, help="measuring time per mode and round")
    parser.add_argument("--rounds", type=int, default=3, help="rounds of the interleaved modes")
    parser.add_argument("--episodes", type=int, default=2, help="expert episodes recorded per task and mode")
    parser.add_argument("--no-sizes", action="store_true", help="skip the recordings (dataset and MCAP sizes)")
    args = parser.parse_args()
    if args.seconds <= 0 or args.rounds < 1 or args.episodes < 1:
        parser.error("--seconds must be > 0, --rounds and --episodes >= 1")
    print(
        f"machine: {os.cpu_count()} CPUs, {platform.platform()}, Python {platform.python_version()}; "
        f"renderer: {check_vulkan().detail}"
    )
    for task in args.task:
        print_rates(task, step_rates(task, args.modes, args.seconds, args.rounds), args.seconds, args.rounds)
    if args.no_sizes:
        return
    recordable = [m for m in args.modes if m in RECORDABLE]
    with tempfile.TemporaryDirectory(prefix="kitbench-bench-") as tmp:
        for task in args.task:
            print_sizes(task, recordable, args.episodes, Path(tmp))


if __name__ == "__main__":
    main()
