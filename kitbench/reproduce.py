"""`kitbench reproduce <config>`: record, train and score one shipped config as published, and say whether the
figure falls inside the published interval.

The published figures live in `policies/published.toml` (docs/learnability.md has the runs behind them). The run
records the config's recipe with the published number of demonstrations (`kitbench record`, resumable), trains
with stock `lerobot-train --config_path=policies/<config>.json` (torch on the cores the config's loader workers
leave, as the published runs did), and scores the last checkpoint with `kitbench eval` on the published suites.
Training minutes are printed beside the published ones scaled to this machine by a fixed reference workload
(`kitbench.training.reference`) measured in the same run, before the training and again after it.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from kitbench.config.checks import optional, positive_int, seed as seed_check
from kitbench.config.declare import setting, validate
from kitbench.errors import KitbenchError, check_choice

ROOT = Path(__file__).resolve().parents[1]
PUBLISHED = ROOT / "policies" / "published.toml"
THREADS_VAR = "OMP_NUM_THREADS"


@dataclass(frozen=True)
class Published:
    """One config's published figure (`policies/published.toml`)."""

    config: str
    recipe: Path
    demos: int
    steps: int
    seeds: tuple[int, ...]
    suites: tuple[str, ...]
    success: int
    episodes: int
    interval: tuple[float, float]
    train_minutes: float
    eval_batch_size: int = 1
    reference_seconds: float | None = None
    extra: dict = field(default_factory=dict)

    @property
    def rate(self) -> float:
        return self.success / self.episodes


def load_published(path: Path = PUBLISHED) -> dict[str, Published]:
    try:
        table = tomllib.loads(Path(path).read_text())
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise KitbenchError(f"published figures {path} unreadable ({exc})") from None
    known = {"recipe", "demos", "steps", "seeds", "suites", "success", "episodes", "interval", "train_minutes"}
    out = {}
    for name, entry in table.items():
        missing = sorted(known - set(entry))
        if missing:
            raise KitbenchError(f"published figures {path}: [{name}] lacks {', '.join(missing)}")
        out[name] = Published(
            config=name,
            recipe=ROOT / entry["recipe"],
            demos=int(entry["demos"]),
            steps=int(entry["steps"]),
            seeds=tuple(int(s) for s in entry["seeds"]),
            suites=tuple(entry["suites"]),
            success=int(entry["success"]),
            episodes=int(entry["episodes"]),
            interval=(float(entry["interval"][0]), float(entry["interval"][1])),
            train_minutes=float(entry["train_minutes"]),
            eval_batch_size=int(entry.get("eval_batch_size", 1)),
            reference_seconds=entry.get("reference_seconds"),
            extra={k: v for k, v in entry.items() if k not in known},
        )
    return out


@dataclass
class ReproduceConfig:
    # A config in policies/ with a published figure, e.g. act_lift_peg_upright_state.
    config: str = setting(positional=True)
    # The working folder (default outputs/reproduce/<config>; a recording there is resumed).
    out: Path | None = setting(None)
    # Training steps (default: the published run's).
    steps: int | None = setting(None, check=optional(positive_int))
    # Demonstrations (default: the published run's).
    demos: int | None = setting(None, check=optional(positive_int))
    # Each suite's first N seeds (default: all).
    eval_episodes: int | None = setting(None, check=optional(positive_int))
    # lerobot-train --seed (default: the published run's first).
    seed: int | None = setting(None, check=optional(seed_check))
    # Recording and evaluation processes.
    workers: int = setting(1, check=positive_int)
    # A published-figures file.
    published: Path = setting(PUBLISHED, show_default=False)

    def __post_init__(self) -> None:
        self.config = self.config.removesuffix(".json").rsplit("/", 1)[-1]
        self.published = Path(self.published)

    @property
    def folder(self) -> Path:
        return Path(self.out) if self.out is not None else Path("outputs/reproduce") / self.config


def check(config: ReproduceConfig) -> Published:
    published = load_published(config.published)
    check_choice("config", config.config, sorted(published))
    validate(config)
    entry = published[config.config]
    if not (ROOT / "policies" / f"{config.config}.json").is_file():
        raise KitbenchError(f"no config policies/{config.config}.json for the published figure {config.config!r}")
    if not entry.recipe.is_file():
        raise KitbenchError(f"published figure {config.config!r} names recipe {entry.recipe}, which does not exist")
    if config.folder.exists() and not config.folder.is_dir():
        raise KitbenchError(f"output {config.folder} is not a folder; give --out a folder path")
    return entry


def train_threads(config_path: Path) -> str:
    """torch's threads for lerobot-train: the cores the config's loader workers leave, at least one."""
    if os.environ.get(THREADS_VAR):
        return os.environ[THREADS_VAR]
    workers = json.loads(config_path.read_text()).get("num_workers", 4)
    return str(max(1, (os.cpu_count() or 1) - int(workers)))


def train_command(config_path: Path, data: Path, out: Path, steps: int | None, seed: int | None) -> list[str]:
    command = [str(Path(sys.executable).parent / "lerobot-train"), f"--config_path={config_path}"]
    command += [f"--dataset.root={data}", f"--output_dir={out}"]
    if steps is not None:
        command.append(f"--steps={steps}")
    if seed is not None:
        command.append(f"--seed={seed}")
    return command


def reproduce(config: ReproduceConfig, say=print) -> int:
    """Run the whole loop; 0 when the figure falls inside the published interval, 3 when it does not."""
    import shutil

    from kitbench.evaluation.config import EvalConfig
    from kitbench.evaluation.runner import run_eval
    from kitbench.evaluation.stats import wilson_interval
    from kitbench.evaluation.suite import load_suite
    from kitbench.recording.recorder import load_recipe, record
    from kitbench.training.reference import reference_seconds, scaled_minutes

    entry = check(config)
    config_path = ROOT / "policies" / f"{config.config}.json"
    demos = config.demos or entry.demos
    seed = entry.seeds[0] if config.seed is None else config.seed
    data, train_dir = config.folder / "data", config.folder / "train"
    say(f"reproducing {config.config}: {demos} demonstrations from {entry.recipe.name}, training seed {seed}")
    recipe = load_recipe(entry.recipe, episodes=demos, out=data, workers=config.workers)
    recipe = recipe.replace(resume=data.exists(), mcap=False)
    summary = record(recipe)
    if summary.exit_code != 0:
        return summary.exit_code
    threads = train_threads(config_path)
    here = reference_seconds(int(threads))
    command = train_command(config_path, data, train_dir, config.steps, seed)
    if train_dir.exists():  # lerobot-train refuses an existing output folder
        shutil.rmtree(train_dir)
    say(f"training: {THREADS_VAR}={threads} {' '.join(command)}")
    started = time.monotonic()
    env = {**os.environ, THREADS_VAR: threads, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled"}
    log = config.folder / "train.log"
    with log.open("w") as handle:
        status = subprocess.run(command, stdout=handle, stderr=subprocess.STDOUT, env=env, check=False).returncode
    if status != 0:
        tail = "\n".join(log.read_text(errors="replace").splitlines()[-15:])
        raise KitbenchError(f"lerobot-train failed (exit {status}); its log: {log}\n{tail}")
    minutes = (time.monotonic() - started) / 60
    after = reference_seconds(int(threads))  # a machine that slowed down during the training shows it here
    successes = episodes = 0
    for name in entry.suites:
        suite = load_suite(ROOT / "eval" / "suites" / f"{name}.toml")
        if config.eval_episodes is not None:
            suite = suite.first(config.eval_episodes)
        report = run_eval(
            EvalConfig.of(
                suite,
                f"lerobot:{train_dir}",
                config.folder / f"eval_{name}",
                workers=config.workers,
                overwrite=True,
                batch_size=entry.eval_batch_size,
            )
        )
        successes += report["success"]["count"]
        episodes += report["episodes"]
    lo, hi = wilson_interval(successes, episodes)
    rate = successes / episodes
    inside = entry.interval[0] <= rate <= entry.interval[1]
    say(f"\n{config.config}: {successes}/{episodes} = {rate:.1%} (95% CI {lo:.1%}–{hi:.1%})")
    say(
        f"published: {entry.success}/{entry.episodes} = {entry.rate:.1%} ({entry.interval[0]:.1%}–"
        f"{entry.interval[1]:.1%}; training seeds {', '.join(map(str, entry.seeds))}; suites "
        f"{', '.join(entry.suites)})"
    )
    say(f"{'inside' if inside else 'outside'} the published interval")
    scaled = ""
    if entry.reference_seconds:
        there = scaled_minutes(entry.train_minutes, entry.reference_seconds, here)
        scaled = f"; the published {entry.train_minutes:.1f} min are {there:.1f} here"
    say(
        f"training: {minutes:.1f} min for {config.steps or entry.steps} steps (reference workload {here:.1f} s before "
        f"it, {after:.1f} s after{scaled})"
    )
    (config.folder / "reproduce.json").write_text(
        json.dumps(
            {
                "config": config.config,
                "success": successes,
                "episodes": episodes,
                "ci95": [lo, hi],
                "published_interval": list(entry.interval),
                "inside": inside,
                "train_minutes": minutes,
                "reference_seconds": here,
                "reference_seconds_after_training": after,
                "train_command": command,
            },
            indent=1,
        )
        + "\n"
    )
    return 0 if inside else 3
