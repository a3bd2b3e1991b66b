"""What resuming a killed recording costs: `python bench/resume.py [--episodes 200] [--task LiftPegUpright-v1]`.

Records `--episodes` state episodes (MCAP on, the default commit interval) and kills the recorder with SIGKILL as
it stores the episode in the middle (fault point `writer.saved`, a data file open), then times, in this one run:
- **record**: the killed run, from its start to the kill (the first half recorded);
- **resume**: `kitbench record --resume` asked for the episodes the killed run had finished, so it does only what
  resuming costs: checking the folder, bringing back the last commit, republishing the journal, committing;
- **read**: a process that reads the finished folder back as `kitbench eval --policy replay:` or `lerobot-train`
  would (`check_dataset`, the settings and episode facts, stock lerobot's `LeRobotDataset`).
Each is a whole process, start-up included. The resumed dataset is compared with an uninterrupted recording of the
same episodes (frames, episode facts, MCAP logs) before the figures print.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

READ = """
import sys
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from kitbench.integrity import check_dataset
from kitbench.metadata import RecordingInfo, read_episodes
root = sys.argv[1]
check_dataset(root)
RecordingInfo.read(root)
episodes = read_episodes(root)
dataset = LeRobotDataset("kitbench/bench", root=root)
assert dataset.num_episodes == len(episodes)
"""


def _timed(cmd: list[str], env: dict, expect: int = 0) -> float:
    start = time.perf_counter()
    run = subprocess.run(cmd, env=env, cwd=ROOT, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    if run.returncode != expect:
        sys.exit(f"bench/resume.py: {' '.join(cmd[:6])} ... exited {run.returncode}:\n{run.stderr[-3000:]}")
    return seconds


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--task", default="LiftPegUpright-v1")
    args = parser.parse_args(argv)
    if args.episodes < 4:
        parser.error(f"--episodes {args.episodes}: give at least 4")
    from kitbench import faults

    half = args.episodes // 2
    env = {**os.environ, "HF_HUB_OFFLINE": "1"}
    env.pop(faults.OWNER_VAR, None)
    with tempfile.TemporaryDirectory(prefix="kitbench-resume-") as scratch:
        out, reference = Path(scratch) / "ds", Path(scratch) / "reference"
        record = [sys.executable, "-m", "kitbench.cli", "record", "--task", args.task, "--out"]
        killed = _timed(
            [*record, str(out), "--episodes", str(args.episodes)],
            {**env, faults.VAR: f"writer.saved:{half}"},
            expect=-signal.SIGKILL,
        )
        journaled = len(list(Path(f"{out}.journal").glob("seed-*.npz")))
        resumed = _timed([*record, str(out), "--episodes", str(half), "--resume"], env)
        read = _timed([sys.executable, "-c", READ, str(out)], env)
        _timed([*record, str(reference), "--episodes", str(half)], env)
        from tests.datasets_equal import no_leftovers, same_content

        same_content(reference, out)
        no_leftovers(out)
        shutil.rmtree(out)
    print(
        f"{args.task}, state, {args.episodes} episodes killed as episode {half} was stored ({journaled} in the journal)"
    )
    print(f"record the first half : {killed:6.2f} s")
    print(f"resume                : {resumed:6.2f} s  ({resumed / killed:.2f}x the first half)")
    print(f"read the folder back  : {read:6.2f} s  (resume / read: {resumed / read:.2f}x)")
    print("resumed dataset equals the uninterrupted recording of the same episodes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
