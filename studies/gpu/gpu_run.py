"""The image configs on a GPU, in one command per plan: `python studies/gpu/gpu_run.py --plan loader|learn [options]`.

Written for the lent GPU machine (one H100 or H200, 16 cores; `studies/gpu/README.md` says how kitbench is installed
there), where every minute counts: each plan records, trains and scores with the project's own commands, samples
the GPU's utilisation (`nvidia-smi`) while it trains, writes what it measured to `<out>/<plan>.json` after every
step (a killed run keeps its figures), and skips what an earlier run of the same plan already finished.
`--tiny` runs the same steps at a tiny scale on the CPU (2 demonstrations, 2 training steps, 2 episodes scored), which
is how the script is tested before a GPU is lent.

- `loader` (the training input before and after kitbench's reader): for each image config named in `--configs`
  (default the three ACT/Diffusion configs of the issue), its recipe is recorded with `--demos` demonstrations twice,
  rgb stored as video and as the recipe stores it; then `lerobot-train --config_path=<config>` runs `--steps` steps
  on each: "before", lerobot's own reader on video (`KITBENCH_FAST_READER=0`), and "after", kitbench's reader on the
  recipe's storage. Reported per run: samples/s over the last logged interval (lerobot's log, every sixth of the
  steps), data wait and update seconds a step, the seconds the first step waited (loader start), the GPU busy (mean of
  1 s samples from the first logged step to the last, and over the whole run) and its memory, and the minutes the
  config's own step count would take at that rate. `--pipelines after` runs kitbench's reader only; `--extra` (with
  `--tag` naming it) passes more lerobot-train arguments, so that a lever (`--batch_size=256`, `--policy.use_amp=true`)
  is measured beside the config as shipped.
- `learn` (a config trained as shipped and scored): the recipe of `--config` recorded with `--demos` demonstrations
  (or `--data`, a recording made beforehand and carried to the machine: it must suit the config's task and cameras),
  `lerobot-train --config_path=<config>` with `--steps` (default the config's), then `kitbench eval` on the task's
  standard suite on the GPU (`--eval-episodes` of it).
- `score` (how fast the image suite is scored): `kitbench eval --device cuda` of `--checkpoint` (default the loader
  plan's last "after" checkpoint) on its task's standard suite, `--eval-episodes` of it, once per `--score-runs`
  setting (`WORKERSxBATCH`, e.g. `14x10,4x25`); beside them the seconds a bare process takes to import torch and
  lerobot and start CUDA, the start-up every scoring process pays. The success rate of a loader checkpoint (a few
  hundred steps) is no learning figure: the plan times the suite.

Exit status: 2 for a bad argument, 1 when a command fails (its log's tail printed).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import time
from datetime import datetime
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent
LOADER_CONFIGS = ("act_lift_peg_upright_rgb", "act_assembling_kits_rgb", "diffusion_lift_peg_upright_rgb")
LOG_LINE = re.compile(r"step:(\S+) .*?updt_s:([\d.]+) data_s:([\d.]+)")
STEP_TIME = re.compile(r"INFO (\d{4}-\d\d-\d\d \d\d:\d\d:\d\d) \S+ step:")
BATCH = re.compile(r"Effective batch size: (\d+)")
FIRST_STEP = re.compile(r"\|\s*1/\d+ \[(\d+):(\d\d)")


def command(name: str) -> str:
    """A console script of this environment (the lent machine installs them under /tmp/site/bin, on PATH)."""
    here = BIN / name
    return str(here) if here.exists() else (shutil.which(name) or name)


def run(cmd: list[str], log: Path, env: dict | None = None) -> float:
    """Run `cmd` with its output in `log`; its seconds, or exit 1 with the log's tail."""
    log.parent.mkdir(parents=True, exist_ok=True)
    started = time.monotonic()
    with log.open("w") as handle:
        handle.write("$ " + " ".join(cmd) + "\n")
        handle.flush()
        status = subprocess.run(
            cmd, stdout=handle, stderr=subprocess.STDOUT, env={**os.environ, **(env or {})}
        ).returncode
    if status != 0:
        tail = "\n".join(log.read_text(errors="replace").replace("\r", "\n").splitlines()[-25:])
        sys.exit(f"gpu_run: {' '.join(cmd[:3])} ... failed (exit {status}); {log}:\n{tail}")
    return time.monotonic() - started


class GpuSampler:
    """`nvidia-smi` every second in the background: time, utilisation (%) and memory (MiB); nothing without a GPU."""

    def __init__(self, log: Path):
        self.log = log
        self.proc: subprocess.Popen | None = None

    def __enter__(self) -> GpuSampler:
        if shutil.which("nvidia-smi"):
            query = [
                "nvidia-smi",
                "--query-gpu=timestamp,utilization.gpu,memory.used",
                "--format=csv,noheader,nounits",
                "-l",
                "1",
            ]
            self.proc = subprocess.Popen(query, stdout=self.log.open("w"), stderr=subprocess.DEVNULL)
        return self

    def __exit__(self, *exc) -> None:
        if self.proc is not None:
            self.proc.send_signal(signal.SIGTERM)
            self.proc.wait(timeout=10)

    def summary(self, window: tuple[datetime, datetime] | None = None) -> dict:
        return gpu_summary(self.log.read_text() if self.log.is_file() else "", window)


def gpu_summary(samples: str, window: tuple[datetime, datetime] | None) -> dict:
    """Mean busy share over the whole run and over `window` (the logged training steps: start-up, dataset
    loading and the first batch's wait left out, which dominate a short run's mean), and the peak memory."""
    rows = []
    for line in samples.splitlines():
        parts = [p.strip() for p in line.split(",")]
        if len(parts) == 3 and parts[1].isdigit() and parts[2].isdigit():
            rows.append((datetime.strptime(parts[0], "%Y/%m/%d %H:%M:%S.%f"), int(parts[1]), int(parts[2])))
    if not rows:
        return {"gpu_busy_mean": None, "gpu_busy_mean_run": None, "gpu_memory_max_mib": None, "samples": 0}
    inside = [r for r in rows if window is not None and window[0] <= r[0] <= window[1]]
    return {
        "gpu_busy_mean": sum(r[1] for r in inside) / len(inside) if inside else None,
        "gpu_busy_mean_run": sum(r[1] for r in rows) / len(rows),
        "gpu_memory_max_mib": max(r[2] for r in rows),
        "samples": len(inside),
    }


def step_window(log: str) -> tuple[datetime, datetime] | None:
    """From lerobot-train's first logged step to its last: the steady training, by the log's own clock."""
    times = [datetime.strptime(t, "%Y-%m-%d %H:%M:%S") for t in STEP_TIME.findall(log)]
    return (times[0], times[-1]) if len(times) >= 2 else None


def first_step_seconds(log: str) -> float | None:
    """Seconds lerobot-train's progress bar spent on its first step: the loader workers' start and first batch."""
    found = FIRST_STEP.search(log)
    return None if found is None else int(found[1]) * 60 + int(found[2])


def recipe_of(config: str) -> Path:
    root = json.loads((ROOT / "policies" / f"{config}.json").read_text())["dataset"]["root"]
    return ROOT / "datasets" / f"{Path(root).name}.toml"


def record(recipe: Path, demos: int, out: Path, storage: str | None, workers: int, logs: Path) -> float:
    if (out / "meta" / "kitbench_recording.json").is_file():
        return 0.0
    cmd = [command("kitbench"), "record", str(recipe), "--episodes", str(demos), "--out", str(out), "--no-mcap"]
    cmd += ["--workers", str(workers), "--overwrite"]
    if storage is not None:
        cmd += ["--rgb-storage", storage]
    return run(cmd, logs / f"record_{out.name}.log")


def train(config: str, data: Path, out: Path, args, reader: str, logs: Path, steps: int | None) -> dict:
    """lerobot-train on `data`; lerobot's rates over the last third of the steps, and the GPU's."""
    shutil.rmtree(out, ignore_errors=True)
    cmd = [command("lerobot-train"), f"--config_path={ROOT / 'policies' / f'{config}.json'}"]
    cmd += [f"--dataset.root={data}", f"--output_dir={out}", "--dataset.video_backend=pyav"]
    if steps is not None:
        cmd += [f"--steps={steps}", f"--save_freq={steps}", f"--log_freq={max(1, steps // 6)}"]
    cmd += args.extra
    if args.tiny:
        cmd += ["--policy.device=cpu", "--num_workers=0", "--batch_size=2"]
    env = {
        "KITBENCH_FAST_READER": "1" if reader == "kitbench" else "0",
        "HF_HUB_OFFLINE": "1",
        "WANDB_MODE": "disabled",
    }
    name = f"{config}_{out.name}" + (f"_{args.tag}" if args.tag else "")  # a variant keeps its own logs
    sampler = GpuSampler(logs / f"gpu_{name}.csv")
    with sampler:
        seconds = run(cmd, logs / f"train_{name}.log", env)
    text = (logs / f"train_{name}.log").read_text(errors="replace").replace("\r", "\n")
    lines = LOG_LINE.findall(text)
    raw = json.loads((ROOT / "policies" / f"{config}.json").read_text())
    found = BATCH.search(text)
    batch = int(found[1]) if found else raw["batch_size"]
    result = {"seconds": seconds, "batch_size": batch, "first_step_s": first_step_seconds(text)}
    result.update(sampler.summary(step_window(text)))
    if lines:
        _, update, data_wait = lines[-1]
        per_step = float(update) + float(data_wait)
        result.update(update_s=float(update), data_s=float(data_wait), samples_per_s=batch / per_step)
        result["minutes_for_shipped_steps"] = raw["steps"] * per_step / 60
    return result


def save(out: Path, plan: str, results: dict) -> None:
    (out / f"{plan}.json").write_text(json.dumps(results, indent=1) + "\n")


def plan_loader(args, out: Path, logs: Path, results: dict) -> None:
    demos, steps = (2, 2) if args.tiny else (args.demos, args.steps or 600)
    for config in args.configs:
        recipe = recipe_of(config)
        import tomllib

        storage = tomllib.loads(recipe.read_text()).get("record", {}).get("rgb_storage", "video")
        for pipeline, (reader, kind) in {"before": ("stock", "video"), "after": ("kitbench", storage)}.items():
            if pipeline not in args.pipelines:
                continue
            key = f"{config}/{pipeline}" + (f"/{args.tag}" if args.tag else "")
            if key in results:
                continue
            data = out / "data" / f"{recipe.stem}-{kind}"
            record(recipe, demos, data, kind, args.workers, logs)
            results[key] = {
                "reader": reader,
                "storage": kind,
                **train(config, data, out / "train" / pipeline, args, reader, logs, steps),
            }
            save(out, "loader", results)
            print(f"{key}: {json.dumps(results[key])}", flush=True)


def recording_for(config: str, data: Path) -> int:
    """A recording carried to the machine: its episode count, once it is known to suit
    `config` (the same task, every camera the config reads at the config's size); else exit 2 naming the mismatch."""
    meta = json.loads((data / "meta" / "kitbench_recording.json").read_text())
    info = json.loads((data / "meta" / "info.json").read_text())
    raw = json.loads((ROOT / "policies" / f"{config}.json").read_text())
    if meta["task"] != raw["env"]["task"]:
        sys.exit(f"gpu_run: --data {data} records {meta['task']}; {config} trains on {raw['env']['task']}")
    for name, feature in raw["policy"].get("input_features", {}).items():
        if feature["type"] == "VISUAL":
            found = info["features"].get(name, {}).get("shape")
            want = feature["shape"]
            if found is None or sorted(found) != sorted(want):  # the dataset is HWC, the config CHW
                sys.exit(f"gpu_run: --data {data} has {name} {found}; {config} reads it at {want}")
    return info["total_episodes"]


def plan_learn(args, out: Path, logs: Path, results: dict) -> None:
    config = args.config
    demos = 2 if args.tiny else args.demos
    steps = 2 if args.tiny else args.steps
    recipe = recipe_of(config)
    data = out / "data" / f"{recipe.stem}-{demos}"
    if args.data is not None:  # recorded beforehand (studies/gpu/gpu_pack.py carries it): the machine only trains
        data = args.data
        demos = recording_for(config, data)
    key = f"{config}/d{demos}/s{steps or 'shipped'}" + (f"/{args.tag}" if args.tag else "")
    entry = results.setdefault(key, {})
    if "train" not in entry:
        if args.data is None:
            entry["record_seconds"] = record(recipe, demos, data, None, args.workers, logs)
        else:
            entry["data"] = json.loads((data / "meta" / "kitbench_recording.json").read_text())
        entry["train"] = train(config, data, out / "train" / key.replace("/", "_"), args, "kitbench", logs, steps)
        save(out, "learn", results)
    if "eval" not in entry:
        task = "lift_peg_upright" if "lift_peg" in config else "assembling_kits"
        report = out / "eval" / key.replace("/", "_")
        cmd = [command("kitbench"), "eval", "--suite", str(ROOT / "eval" / "suites" / f"{task}.toml")]
        cmd += ["--policy", f"lerobot:{out / 'train' / key.replace('/', '_')}", "--out", str(report), "--overwrite"]
        cmd += ["--episodes", str(2 if args.tiny else args.eval_episodes)]
        cmd += ["--device", "cpu" if args.tiny else "cuda", "--workers", str(1 if args.tiny else args.workers)]
        cmd += ["--batch-size", str(1 if args.tiny else args.eval_batch)]
        seconds = run(cmd, logs / f"eval_{key.replace('/', '_')}.log")
        scored = json.loads((report / "report.json").read_text())
        entry["eval"] = {"seconds": seconds, "success": scored["success"], "failures": scored["failure_categories"]}
        save(out, "learn", results)
    print(f"{key}: {json.dumps(entry)}", flush=True)


def plan_score(args, out: Path, logs: Path, results: dict) -> None:
    checkpoint = Path(args.checkpoint) if args.checkpoint else out / "train" / "after"
    if not (checkpoint / "checkpoints").is_dir():
        sys.exit(f"gpu_run: no checkpoint in {checkpoint} (run --plan loader first, or pass --checkpoint)")
    config = json.loads(next((checkpoint / "checkpoints").glob("*/pretrained_model/train_config.json")).read_text())
    task = "lift_peg_upright" if "LiftPeg" in config["env"]["task"] else "assembling_kits"
    if "startup_seconds" not in results:
        probe = "import torch, lerobot.policies.factory; torch.cuda.is_available() and torch.zeros(1, device='cuda')"
        results["startup_seconds"] = run([sys.executable, "-c", probe], logs / "score_startup.log")
        # the same again with Python's import clock: where the seconds go, package by package
        run([sys.executable, "-X", "importtime", "-c", probe], logs / "score_importtime.log")
        results["startup_imports_s"] = slowest_imports((logs / "score_importtime.log").read_text())
        save(out, "score", results)
    for setting in args.score_runs:
        workers, batch = (1, 1) if args.tiny else setting
        key = f"{task}/{args.eval_episodes}/{workers}x{batch}"
        if key in results:
            continue
        report = out / "eval" / f"score_{workers}x{batch}"
        cmd = [command("kitbench"), "eval", "--suite", str(ROOT / "eval" / "suites" / f"{task}.toml")]
        cmd += ["--policy", f"lerobot:{checkpoint}", "--out", str(report), "--overwrite"]
        cmd += ["--episodes", str(2 if args.tiny else args.eval_episodes), "--device", "cpu" if args.tiny else "cuda"]
        cmd += ["--workers", str(workers), "--batch-size", str(batch)]
        seconds = run(cmd, logs / f"score_{workers}x{batch}.log")
        scored = json.loads((report / "report.json").read_text())
        results[key] = {"seconds": seconds, "workers": workers, "batch_size": batch, "success": scored["success"]}
        save(out, "score", results)
        print(f"{key}: {json.dumps(results[key])}", flush=True)


def slowest_imports(importtime: str, count: int = 12) -> dict[str, float]:
    """From `python -X importtime`'s lines, seconds spent importing each package's own modules (self time, wherever
    in the import tree they were pulled in), slowest first."""
    totals: dict[str, float] = {}
    for line in importtime.splitlines():
        parts = line.split("|")
        if len(parts) == 3 and parts[0].split(":")[-1].strip().isdigit():
            top = parts[2].strip().split(".")[0]
            totals[top] = totals.get(top, 0.0) + int(parts[0].split(":")[-1]) / 1e6
    return {name: round(sec, 3) for name, sec in sorted(totals.items(), key=lambda item: -item[1])[:count]}


def score_setting(text: str) -> tuple[int, int]:
    workers, _, batch = text.partition("x")
    if not (workers.isdigit() and batch.isdigit() and int(workers) >= 1 and int(batch) >= 1):
        raise argparse.ArgumentTypeError(f"{text!r} is not WORKERSxBATCH, e.g. 14x10")
    return int(workers), int(batch)


class OneLineParser(argparse.ArgumentParser):
    """A bad argument is one line naming it, not the usage text."""

    def error(self, message: str):  # type: ignore[override]
        print(f"gpu_run: error: {message}", file=sys.stderr)
        raise SystemExit(2)


def main(argv: list[str] | None = None) -> int:
    parser = OneLineParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plan", required=True, choices=("loader", "learn", "score"))
    parser.add_argument("--out", default="outputs/gpu_run", help="results, logs, datasets and checkpoints")
    parser.add_argument("--configs", default=",".join(LOADER_CONFIGS), help="loader: image configs, comma-separated")
    parser.add_argument("--config", default="act_assembling_kits_rgb", help="learn: the config trained and scored")
    parser.add_argument("--demos", type=int, default=50, help="demonstrations recorded per recipe")
    parser.add_argument("--steps", type=int, help="training steps (loader: 600; learn: the config's)")
    parser.add_argument("--data", type=Path, help="learn: a kitbench recording to train on instead of recording one")
    parser.add_argument("--workers", type=int, default=max(1, (os.cpu_count() or 2) - 2), help="recording workers")
    parser.add_argument("--eval-episodes", type=int, default=200, help="learn, score: the suite's first N seeds")
    parser.add_argument("--eval-batch", type=int, default=10, help="learn: kitbench eval --batch-size")
    parser.add_argument("--pipelines", default="before,after", help="loader: before (stock reader), after (kitbench's)")
    parser.add_argument(
        "--extra", default="", help="loader, learn: more lerobot-train arguments: --extra='--batch_size=256'"
    )
    parser.add_argument("--tag", default="", help="loader, learn: a name for the --extra variant in the results")
    parser.add_argument("--checkpoint", help="score: a lerobot-train output folder (default: the loader's last)")
    parser.add_argument("--score-runs", default="14x10", help="score: WORKERSxBATCH settings, comma-separated")
    parser.add_argument("--tiny", action="store_true", help="a tiny end-to-end run on the CPU (the script's test)")
    args = parser.parse_args(argv)
    args.configs = [c.strip() for c in args.configs.split(",") if c.strip()]
    args.extra = shlex.split(args.extra)
    args.pipelines = [p.strip() for p in args.pipelines.split(",") if p.strip()]
    if not args.pipelines or set(args.pipelines) - {"before", "after"}:
        parser.error(f"--pipelines: {','.join(args.pipelines)!r} is not a list of before, after")
    if args.extra and not args.tag:
        parser.error("--extra needs a --tag naming the variant (its results sit beside the config's own)")
    try:
        args.score_runs = [score_setting(s.strip()) for s in args.score_runs.split(",") if s.strip()]
    except argparse.ArgumentTypeError as error:
        parser.error(f"--score-runs: {error}")
    for config in [*args.configs, args.config]:
        if not (ROOT / "policies" / f"{config}.json").is_file():
            parser.error(f"no config policies/{config}.json")
    if min(args.demos, args.workers, args.eval_episodes, args.eval_batch, args.steps or 1) < 1:
        parser.error("--demos, --steps, --workers, --eval-episodes and --eval-batch must be >= 1")
    if args.data is not None and not (args.data / "meta" / "kitbench_recording.json").is_file():
        parser.error(f"--data: {str(args.data)!r} is not a kitbench recording (no meta/kitbench_recording.json)")
    out = Path(args.out)
    logs = out / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    done = out / f"{args.plan}.json"
    results = json.loads(done.read_text()) if done.is_file() else {}
    {"loader": plan_loader, "learn": plan_learn, "score": plan_score}[args.plan](args, out, logs, results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
