"""Fingerprints of what kitbench makes, to show that a change of code left behaviour alone:
`python bench/fingerprint.py --out a.json [--episodes 3]`, then on the other code `... --out b.json`, then
`python bench/fingerprint.py --compare a.json b.json` (exit 1 when any case differs).

Cases, each through the command line as a user runs it, into a temporary folder:
- every recipe in `datasets/` recorded with `--episodes` episodes (camera recipes 2), no MCAP; one state recipe
  with MCAP (the logs' bytes);
- conversions of a state recording to rgb and to `pd_ee_delta_pose`; DAgger labels (`--policy random --label
  expert`); a replay of a recording; a sharded recording on 2 workers;
- evaluations: expert and random on both short suites, the expert in batches of 4, the first 3 seeds of the
  LiftPegUpright robustness suite, a replayed recording, and `--save-dataset`.

A recording's fingerprint hashes, per episode in order, its seed, length and success, and every numeric column
(actions, executed actions, states, environment states, commanded poses, rewards, dones), and every camera frame as
stock `LeRobotDataset` returns it; a report's, its JSON without timings and paths. Nothing here depends on the
machine's speed: two runs of the same code give the same file.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "HF_HUB_OFFLINE": "1"}
VOLATILE = {"timing", "output", "seconds", "started", "finished", "kitbench_version", "source", "made_by"}


def kitbench(*args: str, cwd: Path) -> None:
    run = subprocess.run(
        [sys.executable, "-m", "kitbench.cli", *args], capture_output=True, text=True, env=ENV, cwd=cwd, check=False
    )
    if run.returncode != 0:
        raise SystemExit(f"fingerprint: kitbench {' '.join(args)} failed:\n{run.stderr[-3000:]}")


def dataset_hash(root: Path) -> str:
    import pandas as pd
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    digest = hashlib.sha256()
    frames = pd.concat([pd.read_parquet(f) for f in sorted((root / "data").rglob("*.parquet"))])
    frames = frames.sort_values(["episode_index", "frame_index"])
    skip = {"timestamp", "index", "task_index"}
    for name in sorted(c for c in frames.columns if c not in skip):
        values = frames[name].to_numpy()
        if values.dtype == object and len(values) and isinstance(values[0], dict):
            continue  # images: hashed below as lerobot returns them
        digest.update(name.encode())
        digest.update(np.ascontiguousarray(np.stack(values) if values.dtype == object else values).tobytes())
    lines = (root / "meta" / "kitbench_episodes.jsonl").read_text().splitlines()
    for line in lines:
        episode = json.loads(line)
        digest.update(json.dumps({k: episode[k] for k in ("seed", "success", "length")}, sort_keys=True).encode())
    dataset = LeRobotDataset("kitbench/fingerprint", root=root, video_backend="pyav", return_uint8=True)
    for key in dataset.meta.camera_keys:
        for i in range(len(dataset)):
            digest.update(dataset[i][key].numpy().tobytes())
    return digest.hexdigest()


def report_hash(folder: Path) -> str:
    def strip(value):
        if isinstance(value, dict):
            return {k: strip(v) for k, v in value.items() if k not in VOLATILE}
        if isinstance(value, list):
            return [strip(v) for v in value]
        return value

    report = strip(json.loads((folder / "report.json").read_text()))
    return hashlib.sha256(json.dumps(report, sort_keys=True).encode()).hexdigest()


def mcap_hash(root: Path) -> str:
    digest = hashlib.sha256()
    for path in sorted((root / "mcap").glob("*.mcap")):
        digest.update(path.read_bytes())
    return digest.hexdigest()


def fingerprints(episodes: int, work: Path) -> dict[str, str]:
    out: dict[str, str] = {}
    for recipe in sorted((ROOT / "datasets").glob("*.toml")):
        camera = "rgb" in recipe.stem
        kitbench("record", str(recipe), "--episodes", str(2 if camera else episodes), "--out", recipe.stem,
                 "--no-mcap", "--workers", "1", cwd=work)  # fmt: skip
        out[f"record {recipe.stem}"] = dataset_hash(work / recipe.stem)
        print(f"record {recipe.stem}: {out[f'record {recipe.stem}'][:12]}", flush=True)
    # paths relative to the scratch folder: a report names its policy's dataset, which must not vary between runs
    source = "lift_peg_upright_state"
    kitbench("record", "--task", "AssemblingKits-v1", "--episodes", "2", "--out", "mcap", cwd=work)
    out["record with mcap"] = dataset_hash(work / "mcap") + mcap_hash(work / "mcap")
    cases = {
        "convert rgb": ["convert", source, "--out", "cv_rgb", "--obs-mode", "rgb", "--no-mcap"],
        "convert ee": ["convert", source, "--out", "cv_ee", "--control-mode", "pd_ee_delta_pose"],
        "dagger": ["record", "--task", "LiftPegUpright-v1", "--episodes", "2", "--policy", "random", "--label",
                   "expert", "--out", "dagger", "--no-mcap"],
        "replay": ["record", "--task", "LiftPegUpright-v1", "--episodes", str(episodes), "--policy",
                   f"replay:{source}", "--control-mode", "pd_joint_pos", "--out", "replay", "--no-mcap"],
        "shards": ["record", "--task", "LiftPegUpright-v1", "--episodes", "4", "--shard-episodes", "2", "--workers",
                   "2", "--out", "shards", "--no-mcap"],
    }  # fmt: skip
    for name, args in cases.items():
        kitbench(*args, cwd=work)
        out[name] = dataset_hash(work / args[args.index("--out") + 1])
        print(f"{name}: {out[name][:12]}", flush=True)
    evals = {
        "eval expert lpu": ["--suite", "eval/suites/lift_peg_upright_short.toml", "--policy", "expert"],
        "eval random lpu": ["--suite", "eval/suites/lift_peg_upright_short.toml", "--policy", "random"],
        "eval expert ak": ["--suite", "eval/suites/assembling_kits_short.toml", "--policy", "expert"],
        "eval random ak": ["--suite", "eval/suites/assembling_kits_short.toml", "--policy", "random"],
        "eval expert batch 4": ["--suite", "eval/suites/lift_peg_upright_short.toml", "--batch-size", "4"],
        "eval robustness": ["--suite", "eval/suites/lift_peg_upright_robustness.toml", "--episodes", "3"],
        "eval replay": ["--task", "LiftPegUpright-v1", "--seed", "0", "--episodes", str(episodes), "--policy",
                        "replay:replay"],
        "eval save dataset": ["--task", "LiftPegUpright-v1", "--episodes", "2", "--save-dataset", "saved"],
    }  # fmt: skip
    for name, args in evals.items():
        folder = name.replace(" ", "_")
        kitbench("eval", *[str(ROOT / a) if a.startswith("eval/suites/") else a for a in args], "--out", folder,
                 cwd=work)  # fmt: skip
        out[name] = report_hash(work / folder)
        print(f"{name}: {out[name][:12]}", flush=True)
    out["eval saved dataset"] = dataset_hash(work / "saved")
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", help="write the fingerprints here (JSON)")
    parser.add_argument("--episodes", type=int, default=3, help="episodes per state recording (default 3)")
    parser.add_argument("--compare", nargs=2, metavar=("A", "B"), help="compare two fingerprint files")
    args = parser.parse_args()
    if args.compare:
        a, b = (json.loads(Path(p).read_text()) for p in args.compare)
        differ = sorted(k for k in a.keys() | b.keys() if a.get(k) != b.get(k))
        for key in sorted(a.keys() | b.keys()):
            print(f"{'same' if key not in differ else 'DIFFERENT':9} {key}")
        print(f"{len(differ)} of {len(a.keys() | b.keys())} cases differ")
        return 1 if differ else 0
    if not args.out or args.episodes < 1:
        parser.error("give --out FILE (and --episodes >= 1), or --compare A B")
    with tempfile.TemporaryDirectory(prefix="kitbench-fingerprint-") as scratch:
        found = fingerprints(args.episodes, Path(scratch))
    Path(args.out).write_text(json.dumps(found, indent=1, sort_keys=True) + "\n")
    print(f"{len(found)} fingerprints written to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
