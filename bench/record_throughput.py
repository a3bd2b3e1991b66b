"""Recording throughput of `kitbench record`: `python bench/record_throughput.py [--task T] [--episodes N] [--no-rgb]`.

Records N expert episodes per cell into a temporary folder for state vs rgb observations, MCAP on vs off, and
1 vs 2 workers, and prints episodes/min, frames/s and MiB per episode with the ratios between cells, all measured
in one run (the machine is shared; compare ratios, not absolute figures across runs), then what the per-episode
journal (durability under kill -9) costs per episode.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
from pathlib import Path

from kitbench.recording.recorder import RecordConfig, record


def cell(task: str, episodes: int, obs_mode: str, mcap: bool, workers: int) -> dict:
    folder = Path(tempfile.mkdtemp(prefix="kitbench-bench-"))
    try:
        s = record(
            RecordConfig(
                task=task, episodes=episodes, out=folder / "ds", obs_mode=obs_mode, mcap=mcap, workers=workers
            ),
            progress=False,
        )
        return {
            "eps_min": 60.0 * s.attempted / s.seconds,
            "fps": s.frames / s.seconds,
            "mib_ep": s.size_bytes / 2**20 / max(s.stored, 1),
            "success": s.successes / s.attempted,
        }
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="LiftPegUpright-v1")
    parser.add_argument("--episodes", type=int, default=12, help="episodes per cell")
    parser.add_argument("--no-rgb", action="store_true", help="skip the camera cells (no Vulkan device)")
    args = parser.parse_args()
    obs_modes = ["state"] if args.no_rgb else ["state", "rgb"]
    if not args.no_rgb:
        cell(args.task, 1, "rgb", False, 1)  # warm-up: the first rendered frame compiles pipelines
    results = {}
    print(f"{args.task}: {args.episodes} expert episodes per cell")
    print(f"{'obs':<6} {'mcap':<5} {'workers':>7} {'episodes/min':>13} {'frames/s':>9} {'MiB/episode':>12}")
    for obs in obs_modes:
        for mcap in (False, True):
            for workers in (1, 2):
                r = results[obs, mcap, workers] = cell(args.task, args.episodes, obs, mcap, workers)
                print(
                    f"{obs:<6} {'on' if mcap else 'off':<5} {workers:>7} {r['eps_min']:>13.1f} {r['fps']:>9.0f} "
                    f"{r['mib_ep']:>12.2f}",
                    flush=True,
                )
    base = results["state", False, 1]["eps_min"]
    print("ratios (episodes/min):")
    for obs in obs_modes:
        print(
            f"  {obs}: mcap on/off {results[obs, True, 1]['eps_min'] / results[obs, False, 1]['eps_min']:.2f}, "
            f"2 workers/1 {results[obs, False, 2]['eps_min'] / results[obs, False, 1]['eps_min']:.2f}"
        )
    if "rgb" in obs_modes:
        print(f"  rgb/state (1 worker, no mcap) {results['rgb', False, 1]['eps_min'] / base:.2f}")
    print("durability: the journal write that makes each finished episode survive kill -9")
    for obs in obs_modes:
        ms, mib = journal_cost(args.task, obs)
        per_episode_ms = 60_000.0 / results[obs, False, 1]["eps_min"]
        print(
            f"  {obs}: {ms:.1f} ms and {mib:.2f} MiB per episode = {100 * ms / per_episode_ms:.1f}% of an episode's "
            f"recording time ({per_episode_ms:.0f} ms)"
        )


def journal_cost(task: str, obs_mode: str, repeats: int = 10) -> tuple[float, float]:
    """Milliseconds and MiB to journal one expert episode with its MCAP log (fsync'd), the median of `repeats`."""
    import statistics
    import time

    from kitbench.policies.registry import make_policy
    from kitbench.recording.journal import EpisodeJournal
    from kitbench.recording.rollout import run_episode
    from kitbench.registration import make_env

    folder = Path(tempfile.mkdtemp(prefix="kitbench-bench-"))
    env = make_env(task, obs_mode=obs_mode)
    episode = run_episode(env, make_policy("expert"), seed=0, mcap_path=folder / "log.mcap")
    env.close()
    try:
        journal = EpisodeJournal(folder / "ds")
        journal.start({})
        times, size = [], 0
        for _ in range(repeats):
            shutil.copy(folder / "log.mcap", folder / "copy.mcap")
            t = time.perf_counter()
            journal.add(episode, folder / "copy.mcap")
            times.append(time.perf_counter() - t)
            size = sum(p.stat().st_size for p in journal.root.glob("seed-*"))
            journal.discard([episode.seed])
        return 1000.0 * statistics.median(times), size / 2**20
    finally:
        shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    main()
