"""What a change costs a recording, against another checkout: `python bench/record_against.py --against DIR
[--cases TASK:MODE,...] [--episodes N] [--rounds R]`.

Records N expert episodes per case (`pd_joint_pos`, no MCAP; default cases AssemblingKits-v1:rgbd and
LiftPegUpright-v1:rgb) with this checkout's kitbench and with the one at DIR (e.g. a `git worktree` of the commit
before the change), each in a process of its own (the checkout and its LeRobot plugin first on PYTHONPATH, this
environment's packages), the two alternating within each of R rounds so that a load spike on the shared machine
hits both alike. Each process first records one episode untimed (lerobot's import, the renderer's pipelines), then
the N timed. Printed per case and checkout, measured in one run: the dataset's bytes per episode (the whole folder,
and its parquet files alone), its number of features, and the recording's episodes/min in each round with their
median.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]
PLUGIN = Path("integrations") / "lerobot_env_kitbench"

# Runs in the checkout's process: argv task, obs mode, episodes, folder; prints one JSON line.
CELL = """
import json, sys, time
from pathlib import Path
from kitbench.recording.recorder import RecordConfig, record
task, mode, episodes, folder = sys.argv[1], sys.argv[2], int(sys.argv[3]), Path(sys.argv[4])
def config(n, seed, out):
    return RecordConfig.of(task, n, out, seed=seed, obs_mode=mode, control_mode="pd_joint_pos", mcap=False)
record(config(1, 10_000, folder / "warmup"), progress=False)
start = time.perf_counter()
summary = record(config(episodes, 0, folder / "ds"), progress=False)
seconds = time.perf_counter() - start
size = lambda root: sum(p.stat().st_size for p in root.rglob("*") if p.is_file())
features = json.loads((folder / "ds" / "meta" / "info.json").read_text())["features"]
print(json.dumps({
    "seconds": seconds, "stored": summary.stored, "frames": summary.frames, "features": len(features),
    "bytes": size(folder / "ds"), "parquet": size(folder / "ds" / "data"),
}))
"""


def cell(checkout: Path, task: str, mode: str, episodes: int) -> dict:
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "PYTHONPATH": f"{checkout}{os.pathsep}{checkout / PLUGIN}"}
    with tempfile.TemporaryDirectory(prefix="kitbench-bench-") as folder:
        run = subprocess.run(
            [sys.executable, "-c", CELL, task, mode, str(episodes), folder],
            capture_output=True,
            text=True,
            env=env,
            cwd=folder,
            check=False,
        )
    if run.returncode != 0:
        raise SystemExit(f"record_against: {checkout} {task} {mode} failed:\n{run.stderr[-3000:]}")
    return json.loads(run.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--against", type=Path, required=True, help="the other checkout (its repository root)")
    parser.add_argument("--cases", default="AssemblingKits-v1:rgbd,LiftPegUpright-v1:rgb", help="TASK:MODE,...")
    parser.add_argument("--episodes", type=int, default=8, help="timed episodes per cell")
    parser.add_argument("--rounds", type=int, default=2, help="rounds of the alternating checkouts")
    args = parser.parse_args()
    if args.episodes < 1 or args.rounds < 1 or not (args.against / "kitbench").is_dir():
        parser.error("--episodes and --rounds must be >= 1, --against a kitbench checkout")
    cases = [tuple(c.split(":", 1)) for c in args.cases.split(",")]
    checkouts = {"against": args.against.resolve(), "this": HERE}
    results: dict = {}
    for r in range(args.rounds):
        for task, mode in cases:
            for name, checkout in checkouts.items():
                results.setdefault((task, mode, name), []).append(cell(checkout, task, mode, args.episodes))
                print(f"round {r + 1}: {task} {mode} {name} done", file=sys.stderr, flush=True)
    print(f"{args.episodes} expert episodes per cell, pd_joint_pos, no MCAP; {args.rounds} round(s), alternating")
    print(f"  this: {HERE}; against: {checkouts['against']}")
    header = f"  {'case':<26} {'checkout':<8} {'features':>8} {'bytes/ep':>10} {'parquet/ep':>11} {'frames/ep':>9}"
    print(header + "  episodes/min per round (median)")
    for task, mode in cases:
        for name in checkouts:
            cells = results[task, mode, name]
            first = cells[0]
            per_episode = {k: first[k] / first["stored"] for k in ("bytes", "parquet", "frames")}
            rates = [60 * c["stored"] / c["seconds"] for c in cells]
            print(
                f"  {task + ' ' + mode:<26} {name:<8} {first['features']:>8} {per_episode['bytes']:>10,.0f} "
                f"{per_episode['parquet']:>11,.0f} {per_episode['frames']:>9.1f}  "
                f"{', '.join(f'{x:.1f}' for x in rates)} ({statistics.median(rates):.1f})",
                flush=True,
            )


if __name__ == "__main__":
    main()
