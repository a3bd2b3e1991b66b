"""`kitbench reproduce <config>`: record, train and score one shipped config as published, and say whether the
figure lands where the published runs predict a new training seed lands.

The published figures live in `policies/published.toml` (docs/learnability.md has the runs behind them). The run
records the config's recipe with the published number of demonstrations (`kitbench record`, resumable), trains
with stock `lerobot-train --config_path=policies/<config>.json` (torch on the published runs' threads, else the
cores the config's loader workers leave), showing its progress as it goes, and scores the last checkpoint with
`kitbench eval` on the published suites: the training and scoring `bench/learnability.py` runs
(`kitbench.training.run`), so a killed reproduction started again reuses what finished, and a finished training
of another request (`--steps`, `--seed`, the threads, the data) is refused before anything runs unless
`--overwrite`. The verdict compares the
run's rate with the 95% prediction interval of a new training seed (`stats.prediction_interval`: this run's
sampling error, the published figure's, and the spread between its training seeds), not with the pooled
figure's own interval, which is narrower than any single run's. Training minutes are printed beside the published
ones scaled to this machine by a fixed reference workload (`kitbench.training.reference`) measured in the same
run, before the training and again after it.
"""

from __future__ import annotations

import json
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from kitbench.config.checks import optional, positive_int, seed as seed_check
from kitbench.config.declare import setting, validate
from kitbench.errors import KitbenchError, check_choice
from kitbench.shipped import ROOT

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
    threads: int | None = None  # torch's threads in the published trainings (default: the cores workers leave)
    seed_success: tuple[int, ...] = ()  # each training seed's successes over every suite, and its episodes
    seed_episodes: tuple[int, ...] = ()
    extra: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not self.seed_success:  # one figure, one run: it stands for itself
            object.__setattr__(self, "seed_success", (self.success,))
            object.__setattr__(self, "seed_episodes", (self.episodes,))

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
            threads=entry.get("threads"),
            seed_success=tuple(entry.get("seed_success", ())),
            seed_episodes=tuple(entry.get("seed_episodes", ())),
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
    # Replace a finished training of another request (steps, seed, threads, data) in --out.
    overwrite: bool = setting(False)

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


def reproduce(config: ReproduceConfig, say=print) -> int:
    """Run the whole loop; 0 when the run lands where the published runs predict a new training seed lands, 3
    when it does not."""
    from kitbench.evaluation.stats import prediction_interval, wilson_interval
    from kitbench.evaluation.suite import load_suite
    from kitbench.recording.recorder import load_recipe, record
    from kitbench.training import run
    from kitbench.training.reference import reference_seconds, scaled_minutes

    entry = check(config)
    config_path = ROOT / "policies" / f"{config.config}.json"
    demos = config.demos or entry.demos
    seed = entry.seeds[0] if config.seed is None else config.seed
    data, policy_dir = config.folder / "data", config.folder / f"seed{seed}"
    say(f"reproducing {config.config}: {demos} demonstrations from {entry.recipe.name}, training seed {seed}")
    recipe = load_recipe(entry.recipe, episodes=demos, out=data, workers=config.workers)
    recipe = recipe.replace(resume=data.exists(), mcap=False)
    threads = run.train_threads(config_path, entry.threads)
    data_stamp = json.dumps(recipe.info().to_json(), sort_keys=True) + f"|{demos}"
    training = run.Training(config_path, data, policy_dir, threads, config.steps, seed, data_stamp=data_stamp)
    run.check_replace(training, config.overwrite)  # before the recording: a refusal costs nothing
    summary = record(recipe)
    if summary.exit_code != 0:
        return summary.exit_code
    here = reference_seconds(int(threads))
    request = training.request()
    say(f"training: {run.shell_line(request['command'], request['env'])}")
    say(f"  its log: {policy_dir / 'train.log'}")
    try:
        trained = run.train(training, progress=True, overwrite=config.overwrite)
    except run.CommandFailed as exc:
        raise KitbenchError(f"lerobot-train failed ({exc}); its log: {exc.log}\n{run.log_tail(exc.log, 15)}") from None
    minutes = trained["seconds"] / 60
    if trained["reused"]:
        say(f"  reused the checkpoint the same command trained ({minutes:.1f} min then)")
    successes = episodes = 0
    control_mode = json.loads(config_path.read_text()).get("env", {}).get("control_mode")
    for name in entry.suites:
        suite = ROOT / "eval" / "suites" / f"{name}.toml"
        first = load_suite(suite).seeds[: config.eval_episodes]
        out = config.folder / f"eval_{name}"
        say(f"scoring on {name} ({len(first)} episodes); its log: {out}.log")
        command = run.eval_command(
            trained["dir"],
            suite,
            out,
            control_mode=control_mode,
            episodes=config.eval_episodes,
            batch_size=entry.eval_batch_size,
            workers=config.workers,
        )
        try:
            report, _ = run.evaluate(command, out, trained["stamp"])
        except run.CommandFailed as exc:
            raise KitbenchError(
                f"kitbench eval failed ({exc}); its log: {exc.log}\n{run.log_tail(exc.log, 15)}"
            ) from None
        successes += report["success"]["count"]
        episodes += report["episodes"]
        say(f"  {report['success']['count']}/{report['episodes']}")
    lo, hi = wilson_interval(successes, episodes)
    rate = successes / episodes
    expected = prediction_interval(list(entry.seed_success), list(entry.seed_episodes), episodes)
    inside = expected[0] <= rate <= expected[1]
    say(f"\n{config.config}: {successes}/{episodes} = {rate:.1%} (95% CI {lo:.1%}–{hi:.1%})")
    say(
        f"published: {entry.success}/{entry.episodes} = {entry.rate:.1%} ({entry.interval[0]:.1%}–"
        f"{entry.interval[1]:.1%}; training seeds {', '.join(map(str, entry.seeds))} at "
        f"{', '.join(f'{s / n:.1%}' for s, n in zip(entry.seed_success, entry.seed_episodes, strict=True))}; suites "
        f"{', '.join(entry.suites)})"
    )
    say(
        f"a new training seed scored on {episodes} episodes is expected at {expected[0]:.1%}–{expected[1]:.1%} (95%: "
        "this run's sampling error, the published figure's and the spread between its training seeds)"
    )
    verdict = (
        "consistent with the published figure"
        if inside
        else ("below" if rate < expected[0] else "above") + " what the published runs predict"
    )
    say(verdict)
    scaled = ""
    if entry.reference_seconds:
        there = scaled_minutes(entry.train_minutes, entry.reference_seconds, here)
        scaled = f"; the published {entry.train_minutes:.1f} min are {there:.1f} here"
    after = trained["reference_after"]
    say(
        f"training: {minutes:.1f} min for {trained['steps']} steps (reference workload {here:.1f} s before it, "
        f"{after:.1f} s after{scaled})"
    )
    (config.folder / "reproduce.json").write_text(
        json.dumps(
            {
                "config": config.config,
                "success": successes,
                "episodes": episodes,
                "ci95": [lo, hi],
                "published_interval": list(entry.interval),
                "expected": list(expected),
                "inside": inside,
                "train_minutes": minutes,
                "reference_seconds": here,
                "reference_seconds_after_training": after,
                "train_command": trained["command"],
            },
            indent=1,
        )
        + "\n"
    )
    return 0 if inside else 3
