"""Where a CPU training update of an image config goes, and what each lever buys, all measured in one run:
`python bench/train_levers.py [--config policies/act_lift_peg_upright_rgb.json ...] [--dataset DIR] [--steps 8]
[--levers baseline,bf16,channels_last,...]`.

Each config is built as `lerobot-train --config_path=<config>` builds it (lerobot's own `make_dataset`,
`make_policy`, pre-processor, optimizer and scheduler) on the dataset its recipe records (`--dataset`: one
recorded at the config's camera size, or record it first), and one update is lerobot-train's own
`update_policy` on a real batch. The baseline is the config as kitbench's lerobot-train commands train it here:
fp32 where the config asks for bf16 autocast on a CPU that computes no bf16 (kitbench.training.precision; `bf16`
measures the autocast there). Per config it prints:
- **parts** of the baseline update: the vision backbone's forward and backward (timed on the batch's images
  alone), the optimizer's step, the rest (the transformer or U-Net, the loss, gradient clipping), and the data
  a batch costs one loader process (`data`: hidden behind the update when a loader worker has a core);
- **levers**, each the baseline with one thing changed, seconds an update (median of `--steps` after warm-up),
  samples/s and the ratio to the baseline: `fp32` (lerobot's `use_amp` off; the baseline's figures, not run
  again, where the baseline trains in fp32), `bf16` (`use_amp` on: bf16
  autocast on the CPU), `mkldnn_bf16`
  (fp32 tensors, oneDNN's convolutions and matrix products computed in bf16: `torch.backends.mkldnn`),
  `channels_last` (the backbone's convolutions in NHWC), `bf16+channels_last`, `size=<W>` (the cameras rendered
  at W x W: images resized, the model sized for them), `batch=<N>` (per-sample cost), `threads=1`, `compile`
  (torch.compile of the model: compile seconds and the steady update), `crop=<N>` (Diffusion's random crop).

Exit status: 2 for a bad argument.
"""

from __future__ import annotations

import argparse
import copy
import json
import statistics
import sys
import tempfile
import time
from contextlib import nullcontext
from pathlib import Path

from kitbench.training import precision

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_CONFIGS = ("act_lift_peg_upright_rgb", "diffusion_lift_peg_upright_rgb", "act_assembling_kits_rgb")
LEVERS = (
    "baseline",
    "fp32",
    "bf16",
    "mkldnn_bf16",
    "channels_last",
    "bf16+channels_last",
    "size=96",
    "size=64",
    "batch=32",
    "batch=64",
    "threads=1",
    "compile",
    "crop=84",
)


def _parse(argv):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", action="append", help="a policies/*.json config (repeatable)")
    parser.add_argument("--dataset", action="append", help="the dataset of each --config, in order")
    parser.add_argument("--steps", type=int, default=8)
    parser.add_argument("--levers", default=",".join(LEVERS))
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--one", help=argparse.SUPPRESS)  # internal: measure this lever of the first config, print JSON
    args = parser.parse_args(argv)
    configs = [Path(c) for c in (args.config or [ROOT / "policies" / f"{n}.json" for n in DEFAULT_CONFIGS])]
    for c in configs:
        if not c.is_file():
            parser.error(f"--config {c}: no such file; give a policies/*.json config")
    datasets = [Path(d) for d in (args.dataset or [])]
    if datasets and len(datasets) != len(configs):
        parser.error(f"--dataset given {len(datasets)} times for {len(configs)} configs; give one per --config")
    levers = [lever.strip() for lever in args.levers.split(",")]
    for lever in levers:
        name, _, value = lever.partition("=")
        known = {lv.partition("=")[0] for lv in LEVERS}
        if name not in known or (value and not value.isdigit()) or (name in ("size", "batch", "crop") and not value):
            parser.error(
                f"--levers: {lever!r} is not a lever; valid: {', '.join(LEVERS)} (size, batch, crop take any N)"
            )
    if args.steps < 2:
        parser.error(f"--steps {args.steps}: give at least 2")
    return args, configs, datasets, levers


class Bench:
    """One config's dataset, batch and policy factory."""

    def __init__(self, config_path: Path, dataset: Path | None, threads: int):
        import torch
        from lerobot.utils.import_utils import register_third_party_plugins

        register_third_party_plugins()  # kitbench's env config and reader, as lerobot-train loads them
        torch.set_num_threads(threads)
        self.threads = threads
        self.raw = json.loads(config_path.read_text())
        self.name = config_path.stem
        self.dataset_root = dataset or ROOT / self.raw["dataset"]["root"]
        # the baseline trains as kitbench's lerobot-train commands do here (kitbench.training.precision)
        self.amp_here = bool(self.raw["policy"].get("use_amp")) and precision.keep_cpu_amp()
        if not (self.dataset_root / "meta" / "info.json").is_file():
            sys.exit(
                f"bench/train_levers.py: no dataset at {self.dataset_root}; record it (kitbench record "
                f"datasets/<recipe>.toml) or give --dataset"
            )

    def cfg(self, **changes):
        """lerobot's TrainPipelineConfig of the config with `changes` (dotted keys) applied, on the CPU."""
        import draccus
        from lerobot.configs.train import TrainPipelineConfig

        raw = copy.deepcopy(self.raw)
        raw["policy"]["device"] = "cpu"
        raw["dataset"]["root"] = str(self.dataset_root)
        raw["num_workers"] = 0
        for key, value in changes.items():
            node = raw
            *path, last = key.split(".")
            for part in path:
                node = node[part]
            node[last] = value
        with tempfile.NamedTemporaryFile("w", suffix=".json", delete=False) as f:
            json.dump(raw, f)
        cfg = draccus.parse(TrainPipelineConfig, config_path=f.name, args=[])
        cfg.validate()
        return cfg


def _images(batch: dict) -> list[str]:
    # (batch, C, H, W), or (batch, observation steps, C, H, W) for Diffusion
    return [k for k, v in batch.items() if k.startswith("observation.images.") and getattr(v, "ndim", 0) >= 4]


def _backbones(policy, cameras: int) -> list:
    """The vision backbone each camera's images go through, in the batch's camera order."""
    import torch

    model = getattr(policy, "model", None)
    if model is not None and hasattr(model, "backbone"):
        return [model.backbone] * cameras  # ACT's ResNet trunk, shared
    encoder = policy.diffusion.rgb_encoder  # Diffusion's: one shared, or one a camera
    return list(encoder) if isinstance(encoder, torch.nn.ModuleList) else [encoder] * cameras


def measure(bench: Bench, lever: str, steps: int) -> dict:
    import torch
    from accelerate import Accelerator
    from lerobot.datasets.factory import make_dataset
    from lerobot.optim.factory import make_optimizer_and_scheduler
    from lerobot.policies import make_policy, make_pre_post_processors
    from lerobot.scripts.lerobot_train import update_policy
    from lerobot.utils.logging_utils import AverageMeter, MetricsTracker

    name, _, value = lever.partition("=")
    changes: dict = {}
    if not bench.amp_here:  # every lever but bf16's runs as kitbench trains here: fp32 on a CPU without bf16
        changes["policy.use_amp"] = False
    if name == "bf16" or name == "bf16+channels_last":
        changes["policy.use_amp"] = True
    if name == "fp32":  # a config shipped with use_amp measured without it
        changes["policy.use_amp"] = False
    if name == "batch":
        changes["batch_size"] = int(value)
    if name == "crop":
        if bench.raw["policy"]["type"] != "diffusion":
            return {"skipped": "no crop in this policy"}
        changes["policy.crop_shape"] = [int(value), int(value)]
    size = int(value) if name == "size" else None
    if size is not None:  # feature names hold dots: the whole table is replaced
        features = copy.deepcopy(bench.raw["policy"].get("input_features", {}))
        for feature in features.values():
            if feature["type"] == "VISUAL":
                feature["shape"] = [3, size, size]
        changes["policy.input_features"] = features
        if bench.raw["policy"].get("crop_shape"):
            crop = bench.raw["policy"]["crop_shape"][0] * size // 128
            changes["policy.crop_shape"] = [crop, crop]
    cfg = bench.cfg(**changes)
    torch.set_num_threads(1 if name == "threads" else bench.threads)
    torch.manual_seed(0)
    dataset = make_dataset(cfg)
    policy = make_policy(cfg=cfg.policy, ds_meta=dataset.meta)
    preprocessor, _ = make_pre_post_processors(cfg.policy, dataset_stats=dataset.meta.stats)
    optimizer, scheduler = make_optimizer_and_scheduler(cfg, policy)
    loader = torch.utils.data.DataLoader(
        dataset, batch_size=cfg.batch_size, shuffle=True, num_workers=0, drop_last=True
    )
    started = time.perf_counter()
    batches = [next(iter(loader)) for _ in range(2)]
    data = (time.perf_counter() - started) / 2
    batches = [preprocessor(b) for b in batches]
    if size is not None:
        for b in batches:
            for key in _images(b):
                image = b[key]
                flat = torch.nn.functional.interpolate(
                    image.flatten(0, -4), size=(size, size), mode="bilinear", antialias=True
                )
                b[key] = flat.reshape(*image.shape[:-2], size, size)
    channels_last = name in ("channels_last", "bf16+channels_last")
    if channels_last:  # as a training loop of one's own would (lerobot's checkpoint can't save its optimizer state)
        policy = policy.to(memory_format=torch.channels_last)
        for b in batches:
            for key in _images(b):
                if b[key].ndim == 4:  # Diffusion's (batch, steps, C, H, W) meets the channels-last weights flattened
                    b[key] = b[key].contiguous(memory_format=torch.channels_last)
    compile_seconds = None
    if name == "compile":
        started = time.perf_counter()
        try:
            policy.forward = torch.compile(policy.forward)
        except Exception as exc:  # noqa: BLE001  (reported, not raised: the bench goes on with the other levers)
            return {"skipped": f"torch.compile failed: {type(exc).__name__}: {str(exc)[:100]}"}
    accelerator = Accelerator(cpu=True, mixed_precision="bf16" if cfg.policy.use_amp else "no")
    torch.backends.mkldnn.fp32_precision = "bf16" if name == "mkldnn_bf16" else "none"
    metrics = MetricsTracker(
        cfg.batch_size,
        1,
        1,
        {
            "loss": AverageMeter("loss"),
            "grad_norm": AverageMeter("g"),
            "lr": AverageMeter("lr"),
            "update_s": AverageMeter("u"),
        },
    )
    times = []
    for i in range(steps + 2):
        t = time.perf_counter()
        try:
            update_policy(
                metrics,
                policy,
                batches[i % 2],
                optimizer,
                cfg.optimizer.grad_clip_norm,
                accelerator,
                lr_scheduler=scheduler,
            )
        except Exception as exc:  # noqa: BLE001
            return {"skipped": f"{lever} failed: {type(exc).__name__}: {str(exc)[:100]}"}
        times.append(time.perf_counter() - t)
        if name == "compile" and i == 0:
            compile_seconds = times[-1]
    torch.backends.mkldnn.fp32_precision = "none"
    update = statistics.median(times[2:])
    out = {
        "update": update,
        "samples_per_s": cfg.batch_size / update,
        "batch": cfg.batch_size,
        "data": data,
        "compile_seconds": compile_seconds,
    }
    if name == "baseline":
        # the backbone timed as the update runs it: under bf16 autocast when the config trains with use_amp
        amp = (lambda: torch.autocast("cpu", dtype=torch.bfloat16)) if cfg.policy.use_amp else nullcontext
        out.update(_parts(policy, batches[0], optimizer, steps, amp))
    return out


def _parts(policy, batch, optimizer, steps: int, context) -> dict:
    """The baseline update's parts: the backbone's forward and backward on the batch's images, the optimizer."""
    import torch

    images = [batch[k] for k in _images(batch)]
    backbones = _backbones(policy, len(images))
    times = []
    for _ in range(steps):
        t = time.perf_counter()
        with context():
            for image, backbone in zip(images, backbones, strict=True):
                x = image.flatten(0, -4) if image.ndim > 4 else image
                out = backbone(x)
                out = out["feature_map"] if isinstance(out, dict) else out
                out.float().sum().backward()
        times.append(time.perf_counter() - t)
    optimizer.zero_grad()
    step_times = []
    for _ in range(steps):
        for p in policy.parameters():
            p.grad = torch.zeros_like(p)
        t = time.perf_counter()
        optimizer.step()
        step_times.append(time.perf_counter() - t)
    optimizer.zero_grad()
    return {"backbone": statistics.median(times), "optimizer": statistics.median(step_times)}


def _in_own_process(config: Path, dataset: Path | None, lever: str, steps: int, threads: int) -> dict:
    """One lever measured in a fresh process: no state (accelerate's, torch's thread pool, oneDNN's settings, the
    allocator's caches) carries from one lever to the next."""
    import subprocess

    cmd = [sys.executable, __file__, "--config", str(config), "--steps", str(steps), "--threads", str(threads)]
    cmd += ["--one", lever, *(["--dataset", str(dataset)] if dataset else [])]
    run = subprocess.run(cmd, capture_output=True, text=True)
    if run.returncode != 0:
        return {"skipped": f"failed: {run.stderr.strip().splitlines()[-1] if run.stderr.strip() else run.returncode}"}
    return json.loads(run.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    args, configs, datasets, levers = _parse(argv)
    if args.one:
        bench = Bench(configs[0], datasets[0] if datasets else None, args.threads)
        print(json.dumps(measure(bench, args.one, args.steps)))
        return 0
    for i, path in enumerate(configs):
        dataset = datasets[i] if datasets else None
        bench = Bench(path, dataset, args.threads)  # its dataset is there, before any lever runs
        print(f"\n{path.stem} ({args.threads} threads, {args.steps} updates a lever, each lever a fresh process)")
        if bench.raw["policy"].get("use_amp") and not bench.amp_here:
            print(f"  each lever but bf16 as kitbench trains here: {precision.why((precision.OFF_FLAG,))}")
        base = None
        fp32_base = not (bench.raw["policy"].get("use_amp") and bench.amp_here)  # the baseline already runs in fp32
        for lever in levers:
            if lever == "fp32" and fp32_base and base:  # the same path again: its figures are the baseline's
                print(
                    f"  {lever:<20} {base['update']:.3f} s/update  {base['samples_per_s']:6.1f} samples/s  1.00x "
                    "(the baseline: it trains in fp32 here)"
                )
                continue
            result = _in_own_process(path, dataset, lever, args.steps, args.threads)
            if "skipped" in result:
                print(f"  {lever:<20} {result['skipped']}")
                continue
            if lever == "baseline":
                base = result
                rest = result["update"] - result["backbone"] - result["optimizer"]
                print(
                    f"  parts of one update (batch {result['batch']}): backbone fwd+bwd {result['backbone']:.3f} s, "
                    f"optimizer {result['optimizer']:.3f} s, transformer/U-Net and the rest {rest:.3f} s; "
                    f"data for a batch on one process {result['data']:.3f} s"
                )
            per_sample = result["update"] / result["batch"]
            ratio = (base["update"] / base["batch"]) / per_sample if base else 1.0
            extra = f"  (compiled in {result['compile_seconds']:.0f} s)" if result.get("compile_seconds") else ""
            print(
                f"  {lever:<20} {result['update']:.3f} s/update  {result['samples_per_s']:6.1f} samples/s  "
                f"{ratio:4.2f}x{extra}"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
