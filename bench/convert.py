"""What `kitbench convert` reproduces and what it saves: `python bench/convert.py [--task T] [--episodes N]`.

For each task (default: both) it records N expert episodes (default 50) in each source control mode (`--sources`,
default pd_joint_delta_pos and pd_joint_pos; state observations, no MCAP), converts each into every other control
mode of `--targets`, and prints per conversion the episodes stored (reproduced: same success, every object within
the tolerance of its source pose) out of N and the conversion's episodes/min. Then, from the first source, it
converts to rgb and records the same seeds with rgb from scratch, and prints both speeds and their ratio, measured
in one run (what re-rendering saves is the expert's planning).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import kitbench
from kitbench.recording.convert import convert_config
from kitbench.recording.recorder import RecordConfig, record
from kitbench.recording.source import SourceRecording

MODES = "pd_joint_delta_pos,pd_joint_pos,pd_joint_target_delta_pos,pd_ee_delta_pose,pd_ee_target_delta_pose"


def timed(config) -> tuple[object, float]:
    start = time.perf_counter()
    summary = record(config, progress=False)
    return summary, time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", action="append", choices=sorted(kitbench.TASKS), help="default: every task")
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--sources", default="pd_joint_delta_pos,pd_joint_pos")
    parser.add_argument("--targets", default=MODES)
    parser.add_argument("--no-rgb", action="store_true", help="skip the camera conversion (no Vulkan device)")
    args = parser.parse_args()
    n = args.episodes
    for task in args.task or list(kitbench.TASKS):
        with tempfile.TemporaryDirectory(prefix="kitbench-convert-") as scratch:
            base = Path(scratch)
            print(f"{task}: {n} expert episodes per source, state observations")
            print(f"  {'source':<26} {'target':<26} {'reproduced':>10} {'episodes/min':>13}")
            sources = {}
            for mode in args.sources.split(","):
                root = base / f"src_{mode}"
                record(RecordConfig.of(task, n, root, control_mode=mode, mcap=False), progress=False)
                sources[mode] = root
                for target in args.targets.split(","):
                    if target == mode:
                        continue
                    out = base / f"{mode}_to_{target}"
                    summary, seconds = timed(convert_config(root, out, control_mode=target, mcap=False))
                    rate = 60 * summary.attempted / seconds
                    print(f"  {mode:<26} {target:<26} {summary.stored:>5}/{n:<4} {rate:>13.0f}")
            if args.no_rgb:
                continue
            first = next(iter(sources))
            print("  " + rgb_against_recording(task, sources[first], base, n, workers=1))


def rgb_against_recording(task: str, source: Path, scratch: Path, n: int, workers: int) -> str:
    """Converts the recording `source` (n expert episodes of `task`) to rgb and records its seeds with rgb from
    scratch, one after the other, both with `workers`: one line with both speeds, their ratio and the successes
    reproduced (what re-rendering saves is the expert's planning)."""
    mode = SourceRecording(source).settings["control_mode"]
    # untimed: the first rendered frame of a process compiles its pipelines, which the first timed run would pay
    record(
        RecordConfig.of(task, 1, scratch / "rgb_warm_up", control_mode=mode, obs_mode="rgb", mcap=False), progress=False
    )
    converted, c_s = timed(
        convert_config(source, scratch / "rgb_converted", obs_mode="rgb", mcap=False, workers=workers)
    )
    direct_config = RecordConfig.of(
        task, n, scratch / "rgb_direct", control_mode=mode, obs_mode="rgb", mcap=False, workers=workers
    )
    direct, d_s = timed(direct_config)
    c_rate, d_rate = 60 * n / c_s, 60 * n / d_s
    return (
        f"rgb from {mode}, {workers} worker(s): convert {c_rate:.0f} episodes/min ({converted.stored}/{n} "
        f"reproduced), record from scratch {d_rate:.0f} episodes/min ({direct.stored} stored): ratio "
        f"{c_rate / d_rate:.2f}"
    )


if __name__ == "__main__":
    main()
