"""Recording throughput of `kitbench record` per executor: `python bench/record_throughput.py [options]`.

Options: `--task T`, `--episodes N` (per cell, 40), and filters on the cells: `--obs state,rgb,rgb-images`
(`rgb-images`: rgb stored as PNG images, `--rgb-storage images`; `--no-rgb` when there is no Vulkan device),
`--executor local,ray`, `--workers 1,2`, `--mcap on,off` (default on only: the off cells double the run);
`--shard-episodes N` (10: each multi-worker cell is recorded again with shards of N episodes, `--shard-episodes` of
`kitbench record`; 0 skips them); `--ceiling-episodes N` (0 skips the commit ceiling), `--ceiling-sample K`,
`--convert-episodes N` (200; 0 skips the conversion).

Records N expert episodes per cell into a temporary folder, for every combination of the filters, and prints
episodes/min, frames/s and MiB per episode, all measured in one run (the machine is shared; compare ratios, not
absolute figures across runs). Executors: `local` with 1 worker is the in-process executor (episodes run in the
recorder's own process, between its writes: `local:in-proc` in the table), with more a pool of spawned processes
(`local:pool`); `ray` is Ray actors on a local Ray instance the run starts once, as a
user's runs join a running cluster (`ray_address="auto"`; its start-up is printed on its own); each Ray cell starts
and stops its own actors. A cell's time is the wall time of the whole `record()`
call, worker start-up included: validation, starting the workers, the episodes, the commits. Also printed:
`1st ep s`, the seconds from the call until the first episode reached the writer (validation, worker start-up and
one episode), and `steady/min`, the episodes/min at which the second half of the cell's episodes reached it
(start-up and the first write, which imports lerobot and opens the dataset, left out). "Ray overhead" is 1 -
ray/local episodes/min at equal workers: with 1 worker the Ray actor runs episodes while the recorder writes, which
the in-process executor cannot, so it may be negative. A warm-up episode first pays what this process does once
(importing lerobot at the first write; with rgb, setting up the renderer: the first rendered frame compiles
pipelines), which the first cell would otherwise pay alone; pool and Ray workers set up their own, in their
cells' time, as in a real run.

Then the driver commit ceiling: K episodes recorded once in this process (`RecordWork`, real frames and MCAP logs)
are handed N times, under distinct seeds, to the recorder's own write path (`EpisodeJournal.add`, then the
recording session's `store` and `commit`, committing every 30 s and at the end, as `record` does) with no
episode running: the episodes/min and frames/s one writer can take in, whatever the executor. Printed with what one
episode costs the writer (journal, dataset, commits), the bytes that travel from a worker to the writer
(`pickle.dumps((episode, mcap), protocol=5)`), the MiB it takes on disk, and the number of workers one writer can
feed: the ceiling over one worker's steady episodes/min (the 1-worker Ray cell's, else the in-process cell's, which
includes the writes, else the K recorded episodes'), and over the K recorded episodes' bare rate. The journal's
share of an episode's time is what durability under kill -9 costs.

Last, what `kitbench convert` saves: N expert episodes recorded with state observations, then converted to rgb
(`kitbench convert --obs-mode rgb`) and recorded with rgb from scratch, with the most workers of `--workers`, one
after the other (`bench/convert.py`'s comparison): both speeds, their ratio and the successes reproduced.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import math
import pickle
import shutil
import sys
import tempfile
import time
from pathlib import Path

from throughput import counts, executor_label, names, start_ray, timed_engine

from kitbench.recording import recorder
from kitbench.recording.recorder import RecordConfig, record


def cell(
    task: str, episodes: int, obs_mode: str, mcap: bool, executor: str, workers: int, shard_episodes: int = 0
) -> dict:
    folder = Path(tempfile.mkdtemp(prefix="kitbench-bench-"))
    obs_mode, _, storage = obs_mode.partition("-")  # "rgb-images": rgb stored as images (--rgb-storage)
    config = RecordConfig.of(
        task=task,
        episodes=episodes,
        out=folder / "ds",
        obs_mode=obs_mode,
        rgb_storage=storage or "video",
        mcap=mcap,
        workers=workers,
        executor=executor,
        ray_address="auto",
        shard_episodes=shard_episodes,
    )
    try:
        with timed_engine(recorder) as arrivals:
            start = time.perf_counter()
            s = record(config, progress=False)
            seconds = time.perf_counter() - start
        half = arrivals[max(1, len(arrivals) // 2 - 1) :]  # the second half of the intervals, the first left out
        between = half[-1] - half[0] if len(half) > 1 else 0.0
        return {
            "eps_min": 60.0 * s.attempted / seconds,
            "fps": s.frames / seconds,
            "first_s": arrivals[0] - start if arrivals else math.nan,
            "steady": 60.0 * (len(half) - 1) / between if between > 0 else math.nan,
            "mib_ep": s.size_bytes / 2**20 / max(s.stored, 1),
            "success": s.successes / s.attempted,
        }
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def commit_ceiling(task: str, obs_mode: str, mcap: bool, sample: int, episodes: int) -> dict:
    """The recorder's write path alone, fed `episodes` copies (distinct seeds) of `sample` recorded episodes."""
    from kitbench.recording.one_writer import open_session
    from kitbench.recording.work import RecordWork

    folder = Path(tempfile.mkdtemp(prefix="kitbench-bench-"))
    config = RecordConfig.of(task=task, episodes=episodes, out=folder / "ds", obs_mode=obs_mode, mcap=mcap)
    try:
        work = RecordWork(config)
        work.setup()
        try:
            start = time.perf_counter()
            recorded = [work.run(seed) for seed in range(config.demo.seed, config.demo.seed + sample)]
            episode_s = (time.perf_counter() - start) / sample
        finally:
            work.close()
        wire = sum(len(pickle.dumps(r, protocol=5)) for r in recorded) / sample
        session = open_session(config)  # the session as the recorder opens it
        session.start()
        journal = session.journal
        assert journal is not None
        journal_s = publish_s = commit_s = 0.0
        commits = frames = 0
        start = time.perf_counter()
        for i in range(episodes):
            base, log = recorded[i % sample]
            episode = dataclasses.replace(base, seed=config.demo.seed + i)
            t0 = time.perf_counter()
            path = journal.add(episode, log)  # the session's store, its two halves timed apart
            t1 = time.perf_counter()
            session.publish(episode, path)
            frames += episode.length
            t2 = time.perf_counter()
            journal_s, publish_s = journal_s + t1 - t0, publish_s + t2 - t1
            if session.commit_due():
                session.commit()
                commits += 1
                commit_s += time.perf_counter() - t2
        t2 = time.perf_counter()
        session.commit()
        end = time.perf_counter()
        commits, commit_s = commits + 1, commit_s + end - t2
        seconds = end - start
        session.finish()
        disk = sum(p.stat().st_size for p in config.out.rglob("*") if p.is_file())
        return {
            "eps_min": 60.0 * episodes / seconds,
            "fps": frames / seconds,
            "journal_ms": 1000.0 * journal_s / episodes,
            "add_ms": 1000.0 * publish_s / episodes,
            "commit_ms": 1000.0 * commit_s / episodes,
            "commits": commits,
            "wire_mib": wire / 2**20,
            "disk_mib": disk / 2**20 / episodes,
            "episode_s": episode_s,
        }
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def _percent(value: float) -> str:
    return "–" if math.isnan(value) else f"{100 * value:+.0f}%"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="LiftPegUpright-v1")
    parser.add_argument("--episodes", type=int, default=40, help="episodes per cell")
    parser.add_argument(
        "--obs",
        type=names(("state", "rgb", "rgb-images")),
        default=["state", "rgb"],
        help="state,rgb,rgb-images (rgb stored as PNG images, --rgb-storage images)",
    )
    parser.add_argument("--no-rgb", action="store_true", help="skip the camera cells (no Vulkan device)")
    parser.add_argument("--executor", type=names(("local", "ray")), default=None, help="local,ray (default both)")
    parser.add_argument("--workers", type=counts, default=[1, 2], help="worker counts, e.g. 1,2")
    parser.add_argument("--mcap", type=names(("on", "off")), default=["on"], help="on,off (default on)")
    parser.add_argument(
        "--shard-episodes",
        type=int,
        default=10,
        help="also record each multi-worker cell with shards of this many episodes (0: no shard cells)",
    )
    parser.add_argument("--ceiling-episodes", type=int, default=200, help="episodes the writer takes in (0: skip)")
    parser.add_argument("--ceiling-sample", type=int, default=10, help="episodes recorded for the ceiling")
    parser.add_argument(
        "--convert-episodes", type=int, default=200, help="state episodes converted to rgb against recording (0: skip)"
    )
    args = parser.parse_args()
    if args.episodes < 1 or args.ceiling_sample < 1 or min(args.ceiling_episodes, args.convert_episodes) < 0:
        parser.error("--episodes and --ceiling-sample must be >= 1, --ceiling-episodes and --convert-episodes >= 0")
    executors = args.executor or ["local", "ray"]
    if "ray" in executors and importlib.util.find_spec("ray") is None:
        hint = "" if args.executor else "; pass --executor local to skip the Ray cells"
        sys.exit(f"record_throughput: the Ray cells need Ray: pip install 'kitbench[ray]'{hint}")
    ray_start = start_ray(max(args.workers)) if "ray" in executors else None
    obs_modes = ["state"] if args.no_rgb else args.obs
    mcaps = [m == "on" for m in args.mcap]
    # warm-up: the first write imports lerobot, and the first rendered frame compiles pipelines (see the docstring)
    cell(args.task, 1, "rgb" if "rgb" in obs_modes else "state", True, "local", 1)
    results: dict = {}
    print(
        f"{args.task}: {args.episodes} expert episodes per cell; local:in-proc = the in-process executor (1 worker), "
        "ray = actors on the Ray instance started once for the run; times include worker start-up"
    )
    if ray_start is not None:
        print(f"Ray instance started once for the run in {ray_start:.1f} s (not in any cell's time)")
    print(
        f"{'obs':<10} {'mcap':<5} {'executor':<13} {'workers':>7} {'episodes/min':>13} {'frames/s':>9} "
        f"{'1st ep s':>9} {'steady/min':>11} {'MiB/episode':>12} {'Ray overhead':>13}"
    )
    for obs in obs_modes:
        for mcap in mcaps:
            for workers in args.workers:
                for executor in executors:
                    r = results[obs, mcap, executor, workers] = cell(
                        args.task, args.episodes, obs, mcap, executor, workers
                    )
                    local = results.get((obs, mcap, "local", workers))
                    overhead = 1 - r["eps_min"] / local["eps_min"] if executor == "ray" and local else math.nan
                    print(
                        f"{obs:<10} {'on' if mcap else 'off':<5} {executor_label(executor, workers):<13} {workers:>7} "
                        f"{r['eps_min']:>13.1f} {r['fps']:>9.0f} {r['first_s']:>9.1f} {r['steady']:>11.1f} "
                        f"{r['mib_ep']:>12.2f} {_percent(overhead) if executor == 'ray' else '':>13}",
                        flush=True,
                    )
                    if args.shard_episodes and workers > 1:
                        # the shards' own writers: arrivals are shards, so no first-episode or steady figures
                        sharded = results[obs, mcap, executor + "+shards", workers] = cell(
                            args.task, args.episodes, obs, mcap, executor, workers, args.shard_episodes
                        )
                        label = executor_label(executor, workers) + "+shards"
                        print(
                            f"{obs:<10} {'on' if mcap else 'off':<5} {label:<13} "
                            f"{workers:>7} {sharded['eps_min']:>13.1f} {sharded['fps']:>9.0f} {'–':>9} {'–':>11} "
                            f"{sharded['mib_ep']:>12.2f} {'':>13}   shards/one writer "
                            f"{sharded['eps_min'] / r['eps_min']:.2f}",
                            flush=True,
                        )
    print_ratios(results, obs_modes, mcaps, executors, args.workers)
    if args.ceiling_episodes > 0:
        mcap = True if True in mcaps else mcaps[0]
        print_ceiling(args, results, obs_modes, mcap)
    if args.convert_episodes > 0 and "rgb" in obs_modes:
        print_conversion(args.task, args.convert_episodes, max(args.workers))


def print_conversion(task: str, n: int, workers: int) -> None:
    from convert import rgb_against_recording

    with tempfile.TemporaryDirectory(prefix="kitbench-bench-") as scratch:
        source = Path(scratch) / "state"
        start = time.perf_counter()
        record(RecordConfig.of(task, n, source, mcap=False, workers=workers), progress=False)
        state_rate = 60 * n / (time.perf_counter() - start)
        print(f"\n{task}: {n} expert episodes recorded with state at {state_rate:.0f} episodes/min; then")
        print(rgb_against_recording(task, source, Path(scratch), n, workers))


def print_ratios(results: dict, obs_modes: list, mcaps: list, executors: list, workers: list) -> None:
    lines = []
    for obs in obs_modes:
        for mcap in mcaps:
            tag = f"{obs}, mcap {'on' if mcap else 'off'}"
            for executor in executors:
                for w in workers[1:]:
                    ratio = (
                        results[obs, mcap, executor, w]["eps_min"] / results[obs, mcap, executor, workers[0]]["eps_min"]
                    )
                    lines.append(f"  {tag}, {executor}: {w} workers/{workers[0]} {ratio:.2f}")
            if "ray" in executors and "local" in executors:
                for w in workers:
                    ray, local = results[obs, mcap, "ray", w], results[obs, mcap, "local", w]
                    lines.append(
                        f"  {tag}, {w} worker(s): ray/local {ray['eps_min'] / local['eps_min']:.2f} "
                        f"(Ray overhead {_percent(1 - ray['eps_min'] / local['eps_min'])}; steady rate "
                        f"{_percent(1 - ray['steady'] / local['steady'])}; first episode after "
                        f"{ray['first_s']:.1f} s vs {local['first_s']:.1f} s)"
                    )
        if len(mcaps) == 2:
            for executor in executors:
                w = workers[0]
                ratio = results[obs, True, executor, w]["eps_min"] / results[obs, False, executor, w]["eps_min"]
                lines.append(f"  {obs}, {executor}, {w} worker(s): mcap on/off {ratio:.2f}")
    executor, mcap = executors[0], mcaps[0]
    for w in workers:
        tag = f"({executor}, {w} worker(s), mcap {'on' if mcap else 'off'})"
        for top, bottom in (("rgb", "state"), ("rgb-images", "rgb")):
            if top in obs_modes and bottom in obs_modes:
                ratio = results[top, mcap, executor, w]["eps_min"] / results[bottom, mcap, executor, w]["eps_min"]
                lines.append(f"  {top}/{bottom} {tag} {ratio:.2f}")
    if lines:
        print("ratios (episodes/min):")
        print("\n".join(lines))


def _worker_rate(results: dict, obs: str, mcap: bool, ceiling: dict, sample: int) -> tuple[float, str]:
    """One worker's episodes/min, start-up left out (the ceiling is a steady rate too), and where it comes from."""
    sources = (
        ((obs, mcap, "ray", 1), "the 1-worker Ray cell's steady/min (the actor runs while the writer writes)"),
        (
            (obs, mcap, "local", 1),
            "the in-process cell's steady/min (episodes and writes in turn: this overstates the workers fed)",
        ),
    )
    for key, source in sources:
        r = results.get(key)
        if r is not None and not math.isnan(r["steady"]):
            return r["steady"], source
    return 60.0 / ceiling["episode_s"], f"the {sample} episodes recorded for the ceiling"


def print_ceiling(args, results: dict, obs_modes: list, mcap: bool) -> None:
    print(
        f"driver commit ceiling: one writer taking in {args.ceiling_episodes} episodes ({args.ceiling_sample} "
        f"recorded, re-used under distinct seeds), MCAP {'on' if mcap else 'off'}, journal + dataset + commits "
        "every 30 s and at the end, no episode running"
    )
    print(
        f"{'obs':<6} {'episodes/min':>13} {'frames/s':>9} {'journal ms':>11} {'dataset ms':>11} {'commit ms':>10} "
        f"{'commits':>8} {'wire MiB/ep':>12} {'disk MiB/ep':>12} {'worker eps/min':>15} {'workers fed':>12}"
    )
    notes = []
    for obs in obs_modes:
        c = commit_ceiling(args.task, obs, mcap, args.ceiling_sample, args.ceiling_episodes)
        worker, source = _worker_rate(results, obs, mcap, c, args.ceiling_sample)
        print(
            f"{obs:<6} {c['eps_min']:>13.1f} {c['fps']:>9.0f} {c['journal_ms']:>11.1f} {c['add_ms']:>11.1f} "
            f"{c['commit_ms']:>10.1f} {c['commits']:>8} {c['wire_mib']:>12.2f} {c['disk_mib']:>12.2f} "
            f"{worker:>15.1f} {c['eps_min'] / worker:>12.1f}",
            flush=True,
        )
        bare = 60.0 / c["episode_s"]
        notes.append(
            f"  {obs}: worker episodes/min from {source}; the {args.ceiling_sample} episodes recorded for the "
            f"ceiling ran at {bare:.1f}/min (no writes, no start-up): {c['eps_min'] / bare:.1f} workers fed; "
            f"the journal (durability under kill -9) is {100 * c['journal_ms'] / (1000 * c['episode_s']):.1f}% of an "
            f"episode's recording time ({1000 * c['episode_s']:.0f} ms)"
        )
    print(
        "  ms columns are per episode: dataset = add_episode (opening a session after each commit included), "
        "commit = all commits over the episodes; workers fed = ceiling / worker episodes/min"
    )
    print("\n".join(notes))


if __name__ == "__main__":
    main()
