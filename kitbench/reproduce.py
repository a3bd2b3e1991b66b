"""`kitbench reproduce <config>`: record, train and score one shipped config as published, and say whether the
figure lands where the published runs predict a new training seed lands.

The published figures live in `policies/published.toml` (docs/results.md has them all). The run
records the config's recipe with the published number of demonstrations (`kitbench record`, resumable), trains
with stock `lerobot-train --config_path=policies/<config>.json` (torch on the published runs' threads, else the
cores the config's loader workers leave), showing its progress as it goes, and scores the last checkpoint with
`kitbench eval` on the published suites: the training and scoring `bench/learnability.py` runs
(`kitbench.training.run`), so a killed reproduction started again reuses what finished, and a finished training
of another request (`--steps`, `--seed`, the threads, the data) is refused before anything runs unless
`--overwrite`. The verdict compares the
run's rate with the 95% prediction interval of a new training seed (`stats.prediction_interval`: this run's
sampling error, the published figure's, and the spread between its training seeds), not with the pooled
figure's own interval, which is narrower than any single run's; where that interval is all of [0, 1] (seeds far
apart, or too few episodes), it gives no verdict and says so. Before the training starts, the published
training minutes are scaled to this machine and printed as what to expect: by the config's own steps timed here
(`kitbench.training.pace`: lerobot-train for a few steps) where the published row keeps its step time, else by a
fixed reference workload (`kitbench.training.reference`) timed here; the workload is timed again as the training
ends, and the training's own step time is read from its log. A reading taken while another process held the cores
says little of the machine; the run says so where it happened.

Each training seed keeps its checkpoint, its reports and its verdict (`reproduce.json`) in `<out>/seed<N>/`,
beside the recording they share (`<out>/data`).

Each step is its own function: `record_data`, `train_policy`, `score`, `verdict`; `reproduce` runs them in order.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from kitbench.config.checks import optional, positive_int, seed as seed_check
from kitbench.config.declare import setting, validate
from kitbench.errors import KitbenchError, check_choice
from kitbench.published import PUBLISHED, Published, load_published
from kitbench.shipped import ROOT
from kitbench.training.reference import Reading, read

if TYPE_CHECKING:  # imported where used: the recorder and the training runner load the simulator's stack
    from kitbench.recording.config import RecordConfig
    from kitbench.training.run import CommandFailed, Training

__all__ = ["PUBLISHED", "Published", "ReproduceConfig", "check", "load_published", "reproduce"]
THREADS_VAR = "OMP_NUM_THREADS"
# kitbench.training.reference's workload timed on N torch threads: the parameter tests measure through.
Reference = Callable[[int], Reading]


@dataclass
class ReproduceConfig:
    # A config in policies/ with a published figure, e.g. act_lift_peg_upright_state.
    config: str = setting(positional=True)
    # The working folder (default outputs/reproduce/<config>): the recording, resumed if there, and a folder per
    # training seed (seed<N>/: its checkpoint, reports and verdict).
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
    # Keep a checkpoint every N training steps as well as the last (lerobot-train --save_freq), for `kitbench select`.
    save_every: int | None = setting(None, check=optional(positive_int))
    # Train a config made for a GPU on this CPU: its model, data, batch and steps, with bf16 autocast where the CPU
    # computes bf16 and one loader worker (a GPU config is refused where torch sees no CUDA without it).
    cpu: bool = setting(False)
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


@dataclass(frozen=True)
class Run:
    """What one reproduction records and trains: the checked request and the entry it reproduces."""

    config: ReproduceConfig
    entry: Published
    config_path: Path
    demos: int
    seed: int
    recipe: RecordConfig
    training: Training

    @property
    def policy_dir(self) -> Path:
        return self.training.policy_dir

    def report_dir(self, suite: str) -> Path:
        """Where this seed's evaluation on `suite` goes: beside its checkpoint, so another seed's never replaces it."""
        return self.policy_dir / f"eval_{suite}"

    @property
    def result(self) -> Path:
        return self.policy_dir / "reproduce.json"


def plan(config: ReproduceConfig) -> Run:
    """The checked request: the recording and the training it asks for, refused before anything runs when it would
    train over a finished training of another request."""
    from kitbench.recording.recorder import load_recipe
    from kitbench.training import device, run

    entry = check(config)
    config_path = ROOT / "policies" / f"{config.config}.json"
    demos = config.demos or entry.demos
    seed = entry.seeds[0] if config.seed is None else config.seed
    data, policy_dir = config.folder / "data", config.folder / f"seed{seed}"
    recipe = load_recipe(entry.recipe, episodes=demos, out=data, workers=config.workers)
    recipe = recipe.replace(resume=data.exists(), mcap=False)
    on_cpu = device.cpu_flags(config_path, config.cpu)
    threads = run.train_threads(config_path, entry.threads_on(bool(on_cpu)), on_cpu=bool(on_cpu))
    data_stamp = json.dumps(recipe.info().to_json(), sort_keys=True) + f"|{demos}"
    extra = on_cpu + (() if config.save_every is None else (f"--save_freq={config.save_every}",))
    training = run.Training(config_path, data, policy_dir, threads, config.steps, seed, extra, data_stamp)
    run.check_replace(training, config.overwrite)  # before the recording: a refusal costs nothing
    return Run(config, entry, config_path, demos, seed, recipe, training)


def record_data(planned: Run, say=print) -> int:
    """Record (or resume) the demonstrations; the recorder's exit status."""
    from kitbench.recording.recorder import record

    entry = planned.entry
    say(
        f"reproducing {planned.config.config}: {planned.demos} demonstrations from {entry.recipe.name}, training "
        f"seed {planned.seed}"
    )
    return record(planned.recipe).exit_code


def expectation(
    entry: Published, here: float, threads: int, steps: int | None = None, step: float | None = None
) -> str:
    """What the training should take on this machine, from the published minutes scaled by a step's seconds here
    (`step`, where the row keeps its own) or else by the two reference workloads."""
    minutes = entry.train_minutes_here(here, steps, step)
    updates = steps or entry.steps
    timed = f"a step {step:.3f} s here, lerobot-train's own timing on {threads} thread(s)" if step else ""
    if minutes is None and step:  # nothing published to scale: the steps timed here alone
        return (
            f"expected training time: its {updates} steps alone take about {updates * step / 60:.1f} min here "
            f"({timed}; the published {entry.train_minutes:.1f} min on {entry.device} came without a step time or "
            "a reference workload)"
        )
    if minutes is None:
        return (
            f"expected training time: not scaled here (the published {entry.train_minutes:.1f} min on "
            f"{entry.device} came without a reference workload); this machine's reference {here:.1f} s on {threads} "
            "thread(s)"
        )
    published = f"published {entry.train_minutes:.1f} min for {entry.steps} on {entry.device}"
    if step and entry.step_seconds:
        return (
            f"expected training time: about {minutes:.1f} min here for {updates} steps ({timed}; {published} at "
            f"{entry.step_seconds:.3f} s a step)"
        )
    if step:  # no published step to scale by: the steps alone, and what the reference workload says beside them
        return (
            f"expected training time: its {updates} steps alone take about {updates * step / 60:.1f} min here "
            f"({timed}; {published} came without a step time; by the reference workload, "
            f"{entry.training_reference:.1f} s there and {here:.1f} s here: about {minutes:.1f} min)"
        )
    return (
        f"expected training time: about {minutes:.1f} min here for {updates} steps ({published}, whose reference "
        f"workload took {entry.training_reference:.1f} s; here {here:.1f} s on {threads} thread(s))"
    )


def busy_warning(reading: Reading, threads: int) -> str:
    """One line saying that another process held the cores while the reference workload was timed before training."""
    return f"the machine was busy before the training: {reading.busy_note(threads)}"


def _reading(seconds: float, share: float | None) -> str:
    """A reference reading as the verdict says it, marked where another process held the cores (unknown: not)."""
    return f"{seconds:.1f} s" + (" (busy)" if share is not None and Reading(seconds, share).busy else "")


def _train_failed(exc: CommandFailed) -> KitbenchError:
    """A failed lerobot-train (the training or its timed steps) as one error with its log's tail."""
    from kitbench.training import run

    return KitbenchError(f"lerobot-train failed ({exc}); its log: {exc.log}\n{run.log_tail(exc.log, 15)}")


def train_policy(planned: Run, say=print, measure: Reference = read) -> tuple[dict, float]:
    """Time the reference workload (and, where the published row keeps its step time, the config's own steps), say
    what the training should take here, then train; or reuse the checkpoint the same request trained, with the
    readings it had. What `run.train` returns, with the step times before and during the training, and the reference
    seconds before it."""
    from kitbench.training import pace, precision, run

    training = planned.training
    threads = int(training.threads)
    reading = measure(threads)
    here = reading.seconds
    step = None
    request = training.request()
    reused = run.finished_request(planned.policy_dir) == request
    if not reused:  # a reused training's readings and steps are its own, from its stamp
        if reading.busy:
            say(busy_warning(reading, threads))
        if planned.entry.step_seconds or pace.reference_misleads(planned.config_path):
            log = planned.policy_dir / pace.PROBE_LOG
            say(f"timing {pace.PROBE_STEPS} steps of lerobot-train here (its log: {log})")
            try:
                step = pace.probe(training)
            except run.CommandFailed as exc:
                raise _train_failed(exc) from None
        say(expectation(planned.entry, here, threads, planned.config.steps, step))
    fp32 = precision.why(tuple(request["command"]))
    if fp32:
        say(fp32)
    say(f"training: {run.shell_line(request['command'], request['env'])}")
    say(f"  its log: {planned.policy_dir / 'train.log'}")
    measured = {"reference_before": here, "reference_share": reading.share, "probe_step_seconds": step}
    try:
        trained = run.train(training, progress=True, overwrite=planned.config.overwrite, measured=measured)
    except run.CommandFailed as exc:
        raise _train_failed(exc) from None
    if trained["reused"]:
        say(f"  reused the checkpoint the same command trained ({trained['seconds'] / 60:.1f} min then)")
        # the readings its training had; a stamp from before they were kept has none, so today's stand in
        measured = {key: trained.get(key, value) for key, value in measured.items()}
    trained = {**trained, **measured, "step_seconds": pace.step_seconds(planned.policy_dir / "train.log")}
    return trained, float(trained["reference_before"])


def score(planned: Run, trained: dict, say=print) -> tuple[int, int]:
    """Score the checkpoint on every published suite; successes and episodes over them all."""
    from kitbench.evaluation.suite import load_suite
    from kitbench.training import run

    config, entry = planned.config, planned.entry
    successes = episodes = 0
    control_mode = json.loads(planned.config_path.read_text()).get("env", {}).get("control_mode")
    for name in entry.suites:
        suite = ROOT / "eval" / "suites" / f"{name}.toml"
        first = load_suite(suite).seeds[: config.eval_episodes]
        out = planned.report_dir(name)
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
    return successes, episodes


def judgement(rate: float, expected: tuple[float, float]) -> str:
    """Where `rate` lies against a new training seed's expected range: consistent, below or above; none where the
    range is all of [0, 1] (published seeds far apart, or too few episodes), which no run can fall outside."""
    if expected == (0.0, 1.0):
        return "none"
    if expected[0] <= rate <= expected[1]:
        return "consistent"
    return "below" if rate < expected[0] else "above"


def verdict(planned: Run, successes: int, episodes: int, trained: dict, here: float, say=print) -> int:
    """Compare the run with where a new training seed lands, say so, write reproduce.json; 0 inside or where no run
    can fall outside, 3 outside."""
    from kitbench.evaluation.stats import prediction_interval, wilson_interval

    config, entry = planned.config, planned.entry
    lo, hi = wilson_interval(successes, episodes)
    rate = successes / episodes
    expected = prediction_interval(list(entry.seed_success), list(entry.seed_episodes), episodes)
    judged = judgement(rate, expected)
    inside = judged in ("consistent", "none")
    say(f"\n{config.config}: {successes}/{episodes} = {rate:.1%} (95% CI {lo:.1%}–{hi:.1%})")
    say(
        f"published: {entry.success}/{entry.episodes} = {entry.rate:.1%} ({entry.interval[0]:.1%}–"
        f"{entry.interval[1]:.1%}; training seeds {', '.join(map(str, entry.seeds))} at "
        f"{', '.join(f'{r:.1%}' for r in entry.seed_rates)}; suites {', '.join(entry.suites)})"
    )
    say(
        f"a new training seed scored on {episodes} episodes is expected at {expected[0]:.1%}–{expected[1]:.1%} (95%: "
        "this run's sampling error, the published figure's and the spread between its training seeds)"
    )
    say(
        {
            "consistent": "consistent with the published figure",
            "below": "below what the published runs predict",
            "above": "above what the published runs predict",
            "none": f"no verdict: at 95% a new training seed scored on {episodes} episodes may land anywhere, so no "
            "rate falls outside the published seeds' spread",
        }[judged]
    )
    minutes, after = trained["seconds"] / 60, trained["reference_after"]
    there = entry.train_minutes_here(here, None, trained["probe_step_seconds"])  # the published run's steps
    scaled = "" if there is None else f"; the published {entry.train_minutes:.1f} min are {there:.1f} here"
    step, before = trained["step_seconds"], trained["probe_step_seconds"]
    timed = "" if before is None else f" ({before:.3f} s timed before it)"
    steps = "" if step is None else f"a step {step:.3f} s{timed}; "
    say(
        f"training: {minutes:.1f} min for {trained['steps']} steps ({steps}reference workload "
        f"{_reading(here, trained.get('reference_share'))} before it, "
        f"{_reading(after, trained.get('reference_after_share'))} after{scaled})"
    )
    result = {
        "config": config.config,
        "success": successes,
        "episodes": episodes,
        "ci95": [lo, hi],
        "published_interval": list(entry.interval),
        "expected": list(expected),
        "inside": inside,
        "verdict": judged,
        "train_minutes": minutes,
        "reference_seconds": here,
        "reference_seconds_after_training": after,
        "reference_share": trained.get("reference_share"),
        "reference_share_after_training": trained.get("reference_after_share"),
        "step_seconds": trained["step_seconds"],
        "probe_step_seconds": trained["probe_step_seconds"],
        "train_command": trained["command"],
    }
    planned.result.write_text(json.dumps(result, indent=1) + "\n")
    return 0 if inside else 3


def reproduce(config: ReproduceConfig, say=print, measure: Reference = read) -> int:
    """Record, train, score and judge: 0 when the run lands where the published runs predict a new training seed
    lands, 3 when it does not. `measure`: the reference workload timed on N threads."""
    planned = plan(config)
    status = record_data(planned, say)
    if status != 0:
        return status
    trained, here = train_policy(planned, say, measure)
    successes, episodes = score(planned, trained, say)
    return verdict(planned, successes, episodes, trained, here, say)
