"""Soak and fault benchmark: `python bench/soak.py [--episodes 300] [--kills 5] [--resets 1000] [--recorded 200]`.

1. Kill -9: records `--episodes` LiftPegUpright episodes (state, MCAP on), killed with SIGKILL at `--kills` random
   moments and resumed each time; the result must equal an uninterrupted recording of the same settings (frames,
   actions, per-episode metadata, MCAP file names) and load in stock lerobot. Prints what each kill left
   (journaled / committed episodes) and the time lost to restarts.
2. Memory: RSS over `--resets` AssemblingKits resets and over `--recorded` recorded episodes, after a warm-up;
   growth must stay under 5%. Open file descriptors and temporary folders must not grow.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "HF_HUB_OFFLINE": "1"}


def _rss_mib() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _fds() -> int:
    return len(os.listdir("/proc/self/fd"))


def _dataset(out: Path) -> tuple[pd.DataFrame, list[dict]]:
    frames = pd.concat([pd.read_parquet(p) for p in sorted((out / "data").rglob("*.parquet"))])
    episodes = [json.loads(line) for line in (out / "meta/kitbench_episodes.jsonl").read_text().splitlines()]
    return frames.reset_index(drop=True), episodes


def _same(a: Path, b: Path) -> bool:
    fa, ea = _dataset(a)
    fb, eb = _dataset(b)
    if ea != eb or list(fa.columns) != list(fb.columns):
        return False
    if any(not np.array_equal(np.stack(fa[c].to_numpy()), np.stack(fb[c].to_numpy())) for c in fa.columns):
        return False
    return sorted(p.name for p in (a / "mcap").glob("*")) == sorted(p.name for p in (b / "mcap").glob("*"))


def kill_and_resume(episodes: int, kills: int, seed: int) -> None:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from kitbench.recording.journal import EpisodeJournal, journal_root

    work = Path(tempfile.mkdtemp(prefix="kitbench-soak-"))
    try:
        cmd = [
            sys.executable,
            "-m",
            "kitbench.cli",
            "record",
            "--task",
            "LiftPegUpright-v1",
            "--episodes",
            str(episodes),
        ]
        t0 = time.monotonic()
        subprocess.run([*cmd, "--out", str(work / "reference")], env=ENV, cwd=ROOT, check=True, capture_output=True)
        reference_s = time.monotonic() - t0
        out = work / "killed"
        rng = random.Random(seed)
        t0 = time.monotonic()
        for k in range(kills):
            resume = ["--resume"] if out.exists() or journal_root(out).exists() else []
            proc = subprocess.Popen(
                [*cmd, "--out", str(out), *resume],
                env=ENV,
                cwd=ROOT,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
            time.sleep(rng.uniform(3.0, 3.0 + 2.5 * episodes / 60))
            proc.send_signal(signal.SIGKILL)
            proc.wait()
            journaled = len(EpisodeJournal(out).seeds()) if journal_root(out).exists() else 0
            committed = len(_dataset(out)[1]) if (out / "meta/kitbench_episodes.jsonl").is_file() else 0
            print(f"  kill {k + 1}: {committed} committed + {journaled} journaled episodes kept")
        subprocess.run([*cmd, "--out", str(out), "--resume"], env=ENV, cwd=ROOT, check=True, capture_output=True)
        killed_s = time.monotonic() - t0
        same = _same(out, work / "reference")
        loads = LeRobotDataset("kitbench/soak", root=out).num_episodes == episodes
        print(
            f"kill -9 x{kills} over {episodes} episodes: equal to the uninterrupted recording: {same}; "
            f"loads in lerobot: {loads}; {killed_s:.0f} s with kills vs {reference_s:.0f} s uninterrupted"
        )
    finally:
        shutil.rmtree(work, ignore_errors=True)


def memory(resets: int, recorded: int) -> None:
    import gymnasium as gym

    import kitbench  # noqa: F401
    from kitbench.recording.recorder import RecordConfig, record

    env = gym.make("kitbench/AssemblingKits-v1")
    for i in range(50):
        env.reset(seed=i)
    rss0, fds0 = _rss_mib(), _fds()
    for i in range(resets):
        env.reset(seed=1000 + i)
    rss1, fds1 = _rss_mib(), _fds()
    env.close()
    print(
        f"AssemblingKits: {resets} resets after 50 warm-up: RSS {rss0:.1f} -> {rss1:.1f} MiB "
        f"({100 * (rss1 / rss0 - 1):+.2f}%, limit +5%), fds {fds0} -> {fds1}"
    )

    work = Path(tempfile.mkdtemp(prefix="kitbench-soak-"))
    tmp = Path(tempfile.gettempdir())
    try:
        record(RecordConfig.of(task="AssemblingKits-v1", episodes=10, out=work / "warm", mcap=True), progress=False)
        temp_before = set(tmp.iterdir())
        rss0, fds0 = _rss_mib(), _fds()
        record(
            RecordConfig.of(
                task="AssemblingKits-v1", episodes=recorded, out=work / "ds", mcap=True, commit_interval=5.0
            ),
            progress=False,
        )
        rss1, fds1 = _rss_mib(), _fds()
        leftovers = sorted(p.name for p in work.iterdir() if p.name not in ("warm", "ds"))
        new_temp = sorted(p.name for p in set(tmp.iterdir()) - temp_before)
        print(
            f"AssemblingKits: {recorded} recorded episodes after 10 warm-up: RSS {rss0:.1f} -> {rss1:.1f} MiB "
            f"({100 * (rss1 / rss0 - 1):+.2f}%, limit +5%), fds {fds0} -> {fds1}, "
            f"leftovers beside the dataset {leftovers or 'none'}, new temporary files {new_temp or 'none'}"
        )
    finally:
        shutil.rmtree(work, ignore_errors=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=300)
    parser.add_argument("--kills", type=int, default=5)
    parser.add_argument("--resets", type=int, default=1000)
    parser.add_argument("--recorded", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0, help="seeds the kill moments")
    args = parser.parse_args()
    kill_and_resume(args.episodes, args.kills, args.seed)
    memory(args.resets, args.recorded)


if __name__ == "__main__":
    main()
