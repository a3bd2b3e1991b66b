"""What lerobot-train's data loader spends on each sample of the shipped image configs, before and after:
`python bench/train_input.py [options]`.

For each shipped image config (`policies/*_rgb.json`, or `--configs a,b`), its recipe is recorded with
`--episodes` episodes (8) twice, with rgb stored as video (what the recipes stored before) and as the recipe stores
it now (`rgb_storage`), no MCAP logs. Each config's dataset is then built as `lerobot-train` builds it (lerobot's
`make_dataset` on the config, its delta timestamps and image transforms, `--video-backend`, default pyav, the one
decoder every machine has) in four pipelines: stock `LeRobotDataset` on video ("before"), stock on the recipe's
storage, kitbench's reader (`kitbench.training`) on video, and kitbench's reader on the recipe's storage ("after",
what `lerobot-train --config_path=...` now runs). Printed per pipeline, all in one run:

- one loader worker's milliseconds per sample (`--samples` random `dataset[i]` in this process, after a first
  sample that builds kitbench's frame cache), split by stage: the frames (stock's video decoding, several cameras
  on threads at once, each camera's share in brackets; or the cache's read per camera), the image transforms, and
  the rest of `get_item` (row reads with the action chunk, index arithmetic; stock's image storage decodes its PNGs
  there), plus collation (`default_collate` of a batch, per sample). The stages are timed by wrapping the
  functions that do them;
- samples/s of a `torch.utils.data.DataLoader` as lerobot-train builds it (its sampler, batch size and
  prefetching) at 1, 2 and N workers (`--workers`, N the machine's cores), over `--batches` batches after one
  batch per worker;
- the one-time cost kitbench's reader pays: building the frame cache (seconds, MB);
- the ratio of each pipeline's per-sample cost and samples/s to "before".

Then fidelity and size per storage: `--psnr-episodes` episodes (2) re-simulated from their recorded seeds (the
recorder's own `RecordWork`, which renders exactly what was recorded) give the renderer's frames, compared with
what stock `LeRobotDataset` returns for them (PSNR over all pixels, worst pixel error), and the dataset's bytes per
episode (data and videos, no MCAP).

Exit status: 2 for a bad argument, 1 when a recording or a pipeline fails.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import random
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = {p.stem: p for p in sorted((ROOT / "policies").glob("*_rgb.json"))}
BEFORE = ("video", "stock")


def parse_list(text: str, choices=None, kind=str) -> list:
    values = [kind(v.strip()) for v in text.split(",") if v.strip()]
    if not values:
        raise argparse.ArgumentTypeError(f"{text!r}: give at least one value")
    if choices is not None:
        bad = [v for v in values if v not in choices]
        if bad:
            raise argparse.ArgumentTypeError(f"unknown {bad[0]!r}; valid choices: {', '.join(choices)}")
    return values


def worker_counts(text: str) -> list[int]:
    counts = parse_list(text, kind=lambda v: int(v) if v.isdigit() else (os.cpu_count() or 1) if v == "N" else -1)
    if any(c < 0 for c in counts):
        raise argparse.ArgumentTypeError(f"--workers {text!r}: give counts >= 0 or N (the machine's cores)")
    return sorted(set(counts))


# -- recording ------------------------------------------------------------------------------------------
def recipe_of(config: Path) -> Path:
    from kitbench.recording.recorder import load_recipe

    root = json.loads(config.read_text())["dataset"]["root"]
    for path in sorted((ROOT / "datasets").glob("*.toml")):
        if str(load_recipe(path).out) == root:
            return path
    raise SystemExit(f"train_input: no recipe in datasets/ writes {root} (the dataset of {config.name})")


def record(recipe: Path, storage: str, episodes: int, out: Path) -> float:
    """`kitbench record <recipe>` with `storage`; returns the seconds it took."""
    started = time.perf_counter()
    command = [sys.executable, "-m", "kitbench.cli", "record", str(recipe), "--episodes", str(episodes)]
    command += ["--out", str(out), "--rgb-storage", storage, "--no-mcap", "--workers", "1"]
    run = subprocess.run(command, capture_output=True, text=True, cwd=ROOT, check=False)
    if run.returncode != 0:
        raise RuntimeError(f"recording {recipe.name} ({storage}) failed:\n{run.stderr[-2000:]}")
    return time.perf_counter() - started


# -- one pipeline ----------------------------------------------------------------------------------------
class Stages:
    """Seconds spent in each wrapped function, by label."""

    def __init__(self):
        self.seconds: dict[str, float] = defaultdict(float)

    def wrap(self, fn, label):
        def timed(*args, **kwargs):
            started = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                self.seconds[label(*args, **kwargs) if callable(label) else label] += time.perf_counter() - started

        return timed


@contextlib.contextmanager
def patched(obj, name, value):
    old = getattr(obj, name)
    setattr(obj, name, value)
    try:
        yield
    finally:
        setattr(obj, name, old)


def build_dataset(config: Path, data: Path, reader: str, backend: str):
    """The dataset `lerobot-train --config_path=<config> --dataset.root=<data>` trains on, read by `reader`."""
    import draccus
    from lerobot.configs.train import TrainPipelineConfig
    from lerobot.datasets import lerobot_dataset
    from lerobot.datasets.dataset_reader import DatasetReader
    from lerobot.datasets.factory import make_dataset
    from lerobot.policies import ACTConfig, DiffusionConfig  # noqa: F401  (policy choices)

    import lerobot_env_kitbench  # noqa: F401  (the env choice; importing it installs kitbench's reader)
    from kitbench.training.reader import FastReader

    cfg = draccus.parse(
        TrainPipelineConfig,
        config_path=str(config),
        args=[f"--dataset.root={data}", f"--dataset.video_backend={backend}"],
    )
    with patched(lerobot_dataset, "DatasetReader", FastReader if reader == "kitbench" else DatasetReader):
        return cfg, make_dataset(cfg)


def time_samples(dataset, indices: list[int], cameras: list[str]) -> tuple[float, dict[str, float], list]:
    """Seconds per sample over `indices` and the stages' shares; the samples (for collation). Stock decodes several
    cameras on threads at once: its "frames" stage is the wall time of that, each camera's decoding (in brackets)
    the time on its own thread."""
    import torch
    from lerobot.datasets import dataset_reader

    from kitbench.training.frames import FrameCache

    reader = dataset.reader
    stages = Stages()

    def short(key: str) -> str:
        return key.rsplit(".", 1)[-1]

    def decode_label(path, *args, **kwargs):
        return next((f"({short(k)} decoding)" for k in cameras if k in str(path)), "(decoding)")

    transforms = reader._image_transforms
    with contextlib.ExitStack() as stack:
        stack.enter_context(
            patched(
                dataset_reader, "decode_video_frames", stages.wrap(dataset_reader.decode_video_frames, decode_label)
            )
        )
        query = dataset_reader.DatasetReader._query_videos
        stack.enter_context(patched(dataset_reader.DatasetReader, "_query_videos", stages.wrap(query, "frames")))
        for method in ("video", "images"):
            original = getattr(FrameCache, method)
            label = lambda self, key, *a, **k: f"frames {short(key)}"  # noqa: E731
            stack.enter_context(patched(FrameCache, method, stages.wrap(original, label)))
        if transforms is not None:
            reader.set_image_transforms(stages.wrap(transforms, "transforms"))
        torch.manual_seed(0)
        started = time.perf_counter()
        samples = [dataset[i] for i in indices]
        total = (time.perf_counter() - started) / len(indices)
        if transforms is not None:
            reader.set_image_transforms(transforms)
    shares = {label: seconds / len(indices) for label, seconds in stages.seconds.items()}
    shares["rows and the rest"] = total - sum(v for k, v in shares.items() if not k.startswith("("))
    return total, shares, samples


def collation(samples: list, batch: int) -> float:
    from torch.utils.data import default_collate

    batches = [samples[i : i + batch] for i in range(0, len(samples) - batch + 1, batch)] or [samples]
    started = time.perf_counter()
    for chunk in batches:
        default_collate(chunk)
    return (time.perf_counter() - started) / sum(len(c) for c in batches)


def loader_rate(cfg, dataset, workers: int, batches: int) -> float:
    """Samples/s of lerobot-train's DataLoader (its sampler, batch size, prefetching) with `workers` workers."""
    import torch
    from lerobot.datasets import EpisodeAwareSampler

    sampler = EpisodeAwareSampler(
        dataset.meta.episodes["dataset_from_index"],
        dataset.meta.episodes["dataset_to_index"],
        episode_indices_to_use=dataset.episodes,
        drop_n_last_frames=getattr(cfg.policy, "drop_n_last_frames", 0),
        shuffle=True,
        seed=cfg.seed or 0,
        absolute_to_relative_idx=dataset.absolute_to_relative_idx,
    )
    extra = {"prefetch_factor": cfg.prefetch_factor, "persistent_workers": False} if workers else {}
    loader = torch.utils.data.DataLoader(
        dataset, batch_size=cfg.batch_size, sampler=sampler, num_workers=workers, drop_last=False, **extra
    )
    warm = max(1, workers)
    done, samples, started = 0, 0, 0.0
    while done < warm + batches:
        for batch in loader:
            done += 1
            if done == warm:
                started = time.perf_counter()
            elif done > warm:
                samples += len(batch["index"])
            if done >= warm + batches:
                break
    return samples / (time.perf_counter() - started)


def run_pipeline(config: Path, data: Path, reader: str, args) -> dict:
    started = time.perf_counter()
    cfg, dataset = build_dataset(config, data, reader, args.video_backend)
    built = time.perf_counter() - started
    cameras = list(dataset.meta.camera_keys)
    started = time.perf_counter()
    dataset[0]  # kitbench's reader builds its frame cache at the first sample
    first = time.perf_counter() - started
    cache_mb = 0.0
    fast = getattr(dataset.reader, "fast", None)
    if fast is not None and fast.frames is not None and fast.frames.folder is not None:
        cache_mb = sum(p.stat().st_size for p in fast.frames.folder.iterdir()) / 1e6
    rng = random.Random(0)
    indices = [rng.randrange(len(dataset)) for _ in range(args.samples)]
    total, shares, samples = time_samples(dataset, indices, cameras)
    collate = collation(samples, cfg.batch_size)
    rates = {w: loader_rate(cfg, dataset, w, args.batches) for w in args.workers}
    return {
        "ms": 1e3 * (total + collate),
        "stages_ms": {**{k: 1e3 * v for k, v in shares.items()}, "collation": 1e3 * collate},
        "samples_per_s": rates,
        "make_dataset_s": built,
        "first_sample_s": first,
        "cache_mb": cache_mb,
        "frames": len(dataset),
    }


# -- fidelity --------------------------------------------------------------------------------------------
def fidelity(recipe: Path, data: Path, episodes: int) -> dict:
    """PSNR and worst error of the stored frames against the renderer's, over the first `episodes` episodes."""

    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from kitbench.recording.recorder import load_recipe
    from kitbench.recording.work import RecordWork

    seeds = [json.loads(line)["seed"] for line in (data / "meta/kitbench_episodes.jsonl").read_text().splitlines()]
    config = load_recipe(recipe, out=data, episodes=1).replace(mcap=False)
    work = RecordWork(config)
    work.setup()
    dataset = LeRobotDataset("kitbench/bench", root=data, video_backend="pyav", return_uint8=True)
    cameras = list(dataset.meta.camera_keys)
    squared, count, worst = 0.0, 0, 0
    try:
        for episode, seed in enumerate(seeds[:episodes]):
            rendered, _ = work.run(seed)
            start = int(dataset.meta.episodes[episode]["dataset_from_index"])
            for offset, frame in enumerate(rendered.frames):
                item = dataset[start + offset]
                for key in cameras:
                    stored = item[key].numpy()
                    stored = stored if stored.dtype == np.uint8 else np.rint(stored * 255).astype(np.uint8)
                    truth = frame[key].transpose(2, 0, 1).astype(np.int64)
                    error = stored.astype(np.int64) - truth
                    squared += float(np.sum(error**2))
                    count += error.size
                    worst = max(worst, int(np.abs(error).max()))
    finally:
        work.close()
    mse = squared / max(1, count)
    return {"psnr_db": math.inf if mse == 0 else 10 * math.log10(255**2 / mse), "max_error": worst}


def dataset_bytes(data: Path) -> int:
    return sum(p.stat().st_size for folder in ("data", "videos") for p in (data / folder).rglob("*") if p.is_file())


# -- printing --------------------------------------------------------------------------------------------
def label(pipeline: tuple[str, str]) -> str:
    storage, reader = pipeline
    name = f"{reader} reader, {storage}"
    return f"{name} (before)" if pipeline == BEFORE else name


def print_results(results: dict, shipped: dict, workers: list[int]) -> None:
    for config, pipelines in results.items():
        before = pipelines[BEFORE]
        print(f"\n{config}: {before['frames']} frames; after = kitbench reader, {shipped[config]} (the recipe's)")
        head = "| pipeline | ms/sample | vs before | " + " | ".join(f"samples/s {w}w" for w in workers)
        print(head + " | vs before | cache build | stages (ms/sample) |")
        print("|" + "---|" * (5 + len(workers)) + "---|")
        for pipeline, r in pipelines.items():
            rates = " | ".join(f"{r['samples_per_s'][w]:.0f}" for w in workers)
            top = max(workers)
            rate_ratio = r["samples_per_s"][top] / before["samples_per_s"][top]
            stages = ", ".join(f"{k} {v:.2f}" for k, v in r["stages_ms"].items())
            build = f"{r['first_sample_s']:.2f} s, {r['cache_mb']:.0f} MB" if r["cache_mb"] else "-"
            after = (
                " **after**" if pipeline == ("images" if shipped[config] == "images" else "video", "kitbench") else ""
            )
            print(
                f"| {label(pipeline)}{after} | {r['ms']:.2f} | {before['ms'] / r['ms']:.1f}x | {rates} | "
                f"{rate_ratio:.1f}x ({top}w) | {build} | {stages} |"
            )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--configs", type=lambda t: parse_list(t, CONFIGS), default=list(CONFIGS))
    parser.add_argument("--episodes", type=int, default=8, help="episodes recorded per recipe and storage")
    parser.add_argument("--samples", type=int, default=300, help="random samples timed per pipeline")
    parser.add_argument("--batches", type=int, default=10, help="batches timed per DataLoader setting")
    parser.add_argument("--workers", type=worker_counts, default=worker_counts("1,2,N"), help="e.g. 1,2,N")
    parser.add_argument("--video-backend", dest="video_backend", default="pyav", choices=("pyav", "torchcodec"))
    parser.add_argument("--psnr-episodes", dest="psnr_episodes", type=int, default=2, help="0 skips fidelity")
    parser.add_argument("--data", help="keep the recordings here and reuse them on a later run (default: temporary)")
    parser.add_argument("--json", help="also write the figures to this file")
    args = parser.parse_args()
    for name in ("episodes", "samples", "batches"):
        if getattr(args, name) < 1:
            parser.error(f"--{name} must be >= 1, got {getattr(args, name)}")
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    with contextlib.ExitStack() as stack:
        base = Path(args.data) if args.data else Path(stack.enter_context(tempfile.TemporaryDirectory()))
        os.environ.setdefault("KITBENCH_FRAME_CACHE", str(base / "frame-cache"))
        return run(args, base)


def run(args, base: Path) -> int:
    from kitbench.recording.recorder import load_recipe

    results: dict = {}
    shipped: dict = {}
    storage_rows: dict = {}
    for name in args.configs:
        config = CONFIGS[name]
        recipe = recipe_of(config)
        storage = load_recipe(recipe).rgb_storage
        shipped[name] = storage
        pipelines = [("video", "stock"), ("video", "kitbench")]
        if storage != "video":
            pipelines[1:1] = [(storage, "stock")]
            pipelines.append((storage, "kitbench"))
        results[name] = {}
        for kind in dict.fromkeys(s for s, _ in pipelines):
            data = base / f"{recipe.stem}-{kind}"
            if not (data / "meta/info.json").is_file():
                seconds = record(recipe, kind, args.episodes, data)
                print(f"recorded {recipe.name} with rgb as {kind}: {args.episodes} episodes in {seconds:.0f} s")
            if (recipe.stem, kind) not in storage_rows:
                row = {"bytes_per_episode": dataset_bytes(data) / args.episodes}
                if args.psnr_episodes:
                    row.update(fidelity(recipe, data, args.psnr_episodes))
                storage_rows[(recipe.stem, kind)] = row
        for pipeline in pipelines:
            data = base / f"{recipe.stem}-{pipeline[0]}"
            try:
                results[name][pipeline] = run_pipeline(config, data, pipeline[1], args)
            except Exception as exc:  # noqa: BLE001  (report which pipeline failed, then stop)
                print(f"train_input: {name}, {label(pipeline)} failed: {exc!r}", file=sys.stderr)
                return 1
            r = results[name][pipeline]
            print(f"{name}: {label(pipeline)}: {r['ms']:.2f} ms/sample", flush=True)
    print_results(results, shipped, args.workers)
    print("\n| recipe | rgb storage | bytes/episode | vs video | PSNR (dB) | worst pixel error |")
    print("|---|---|---|---|---|---|")
    for (recipe, kind), row in storage_rows.items():
        ratio = row["bytes_per_episode"] / storage_rows[(recipe, "video")]["bytes_per_episode"]
        psnr = row.get("psnr_db")
        shown = "-" if psnr is None else ("exact" if math.isinf(psnr) else f"{psnr:.2f}")
        print(f"| {recipe} | {kind} | {row['bytes_per_episode'] / 1e3:.0f} kB | {ratio:.2f}x | {shown} | "
              f"{row.get('max_error', '-')} |")  # fmt: skip
    if args.json:
        serial = {
            "configs": {n: {f"{s}/{r}": v for (s, r), v in p.items()} for n, p in results.items()},
            "storage": {f"{r}/{k}": v for (r, k), v in storage_rows.items()},
            "machine": {"cores": os.cpu_count()},
        }
        Path(args.json).write_text(json.dumps(serial, indent=1, default=str) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
