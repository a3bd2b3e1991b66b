"""Learnability of kitbench demonstrations: do policies trained with stock `lerobot-train` succeed in `kitbench eval`?

    python bench/learnability.py --task LiftPegUpright-v1 --obs state --demos 50,100,200 --policy act [--steps N]
        [--out outputs/learnability] [--control-mode M] [--action-noise X] [--noise-phases P,Q] [--settle-steps K]
        [--suite-episodes E] [--eval-batch-size B] [--tag NAME] [--config policies/X.json] [--recipe datasets/X.toml]
        [--policy-option KEY=V1[,V2...] ...] [--train-seeds 1000,2000,3000] [--suites standard,heldout] [--overwrite]

For each demo count D (one run each) it records D expert demonstrations from the task's recipe (`kitbench record`),
trains the policy config on them (`lerobot-train`, untouched but for the dataset, output folder and the flags above;
torch gets the cores the config's loader workers leave, at least one: OMP_NUM_THREADS, unless already set),
scores the final checkpoint on the task's standard suite (`kitbench eval`) and prints one row per run: parameters,
training minutes (wall clock: imports, dataset loading and model set-up count), steps/s of the training loop (dated
by lerobot's log; the config's in-training env evaluations count), success k/n with its Wilson 95% interval, the
task's success criteria and failure categories. `--policy-option KEY=V1,V2` (repeatable) sweeps the checkpoint's
inference settings (`kitbench eval --policy-option`): the checkpoint is trained once and scored once per
combination of the values, one row each, its tag carrying the options.

`--train-seeds S1,S2,...` trains once per training seed (lerobot-train's `--seed`; default: the config's own) and
`--suites standard,heldout` scores every checkpoint on each suite (`standard`: eval/suites/<task>.toml, seeds from
1,000,000; `heldout`: eval/suites/<task>_heldout.toml, from 2,000,000; or a suite file's path). A published figure
is then a distribution: the run ends with a pooled table per demo count, the success pooled over every training
seed and suite with its Wilson interval, each suite's pooled rate, the gap between the first two suites with
Newcombe's interval, and each training seed's rate with their spread.

Before anything runs it prints what the run will do and what it will cost: the recordings, trainings and
evaluations, this machine's reference workload (`kitbench.training.reference`: seconds of a fixed update loop on the
training's threads; every row stores it, and the same workload timed again as each training ends, so a machine
that slowed down during a long training shows it), and the hours that makes from the config's published figures
(`policies/published.toml`) scaled by the two machines' reference seconds (for a camera config, whose minutes the
reference does not carry between machines, it says so: docs/learnability.md). Every row keeps its training's own
step time (`step_seconds`, `kitbench.training.pace`), which a published row records beside its minutes. The run is
resumable: a checkpoint whose training finished with the same command, and an evaluation report made by the same
command, are reused, so a killed run started again picks up where it stopped. A finished training of another
request (the command, the threads, the data), or whose recording would be recorded again, is refused in one line
before anything runs; `--overwrite` replaces it.

Each row is appended to <out>/results.jsonl with the exact commands, the machine and the versions, and
<out>/<task>_<obs>_success_vs_demos.png plots success against demos for every (policy, tag) found there, latest row
per demo count: give variants (another config, action noise) their own --tag so their lines stay apart.

Layout: <out>/<task>_<obs>_d<D>[_<tag>]/data (the dataset, record.log) holds what the policies share; each policy
trains and is scored under <policy>/ (<policy>_seed<S>/ with --train-seeds: train/, train.log, eval/, eval.log;
eval_<suite>/ for a suite other than the standard one). A dataset recorded by the same command
from the same recipe with this kitbench version is reused, so a second policy on the same demos skips recording;
a folder that holds another recipe's recording (the folder's name carries no robot) is refused, not recorded over.

Exit status: 2 for a bad argument (nothing written), 1 when a command fails (it and the tail of its log printed).
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import math
import os
import platform
import re
import shlex
import sys
from dataclasses import dataclass
from datetime import UTC, datetime
from importlib.metadata import version
from pathlib import Path

import kitbench
from kitbench.config.files import read_settings
from kitbench.control.controllers import CONTROL_MODES
from kitbench.errors import KitbenchError
from kitbench.evaluation.output import REPORT_JSON
from kitbench.evaluation.plots import error_bars
from kitbench.evaluation.significance import newcombe_interval
from kitbench.evaluation.stats import wilson_interval
from kitbench.evaluation.suite import load_suite
from kitbench.metadata import read_recording_settings
from kitbench.published import Published, load_published
from kitbench.recording.config import RECIPE_KEYS, RECIPE_TABLE, RecordConfig
from kitbench.registration import canonical_task, task_entry
from kitbench.training import pace, run
from kitbench.training.reference import Reading, read

ROOT = Path(__file__).resolve().parents[1]
SUITE_NAMES = {"standard": "{snake}.toml", "heldout": "{snake}_heldout.toml"}
BIN = run.BIN
OBS_CHOICES = ("state", "rgb")
ENV_OBS_TYPE = {"state": "state", "rgb": "pixels_state"}  # the lerobot env config's name for each
# the data never comes from the Hub (dataset.root is local), and a stray lookup must not stall a long run
ENV = run.ENV
# lerobot-train's config has no thread setting. torch's intra-op threads default to one per core, and on a machine
# with few cores they fight the data loader's worker processes for them: ACT 2.65 M on 2 cores, batch 32, trained
# at 8.3 steps/s with torch's 2 threads and 1 worker (9.4 with 0 workers, 8.1 with 2) and at 14.1 steps/s with 1
# thread and 2 workers, whose loading (~2 ms a sample in `datasets`) then runs beside the update instead of against
# it (bench/train_throughput.py, one run). So training gets the cores the workers leave, at least one, unless the
# caller chose.
THREADS_VAR = run.THREADS_VAR
NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*")


class UsageError(Exception):
    """A bad argument, reported before anything is written."""


@dataclass(frozen=True)
class Plan:
    """The checked arguments: what every run shares."""

    task: str
    snake: str
    obs: str
    demos: list[int]
    policy: str
    config: Path
    recipe: Path
    suites: tuple[tuple[str, Path], ...]  # (name, file): each checkpoint is scored on every one
    out: Path
    steps: int | None
    control_mode: str  # the recording's, which training and evaluation must use too
    control_mode_flag: str | None
    config_has_env: bool  # the config evaluates on a kitbench env during training, which needs the control mode
    train_threads: str  # torch's intra-op threads for lerobot-train (OMP_NUM_THREADS)
    action_noise: float | None
    noise_phases: str | None  # comma-separated, as `kitbench record --noise-phases` takes them
    settle_steps: int | None
    suite_episodes: int | None
    eval_batch_size: int
    tag: str | None
    # each combination of the --policy-option values, one evaluation of the trained checkpoint each
    option_sets: tuple[tuple[tuple[str, object], ...], ...] = ((),)
    # lerobot-train's --seed per training; None: the config's own
    train_seeds: tuple[int | None, ...] = (None,)
    progress: bool = True  # the training's steps shown as they come (a line a minute off a terminal)
    overwrite: bool = False  # replace finished trainings of another request, and the recordings they trained on


def parse_sweep(texts: list[str], policy_type: str) -> tuple[tuple[tuple[str, object], ...], ...]:
    """`KEY=V1,V2` flags as every combination of their values, each key checked against the settings a checkpoint
    of the policy takes (a key the policy lacks would only fail after training)."""
    import itertools

    from kitbench.policies.lerobot_policy import option_names, parse_option

    fields = option_names(policy_type)
    axes = []
    for text in texts:
        key, _, values = text.partition("=")
        if key not in fields:
            raise UsageError(f"--policy-option {text!r}: the {policy_type} policy has no setting {key!r}")
        try:
            axes.append([parse_option(f"{key}={value}") for value in values.split(",")])
        except KitbenchError as exc:
            raise UsageError(f"--policy-option {text!r}: {exc}") from None
    return tuple(itertools.product(*axes)) if axes else ((),)


def options_tag(options: tuple[tuple[str, object], ...]) -> str:
    return "+".join(f"{k}={json.dumps(v)}" for k, v in options)


def task_snake(task: str) -> str:
    """LiftPegUpright-v1 -> lift_peg_upright, the stem of the task's recipe, config and suite files."""
    stem = re.sub(r"-v\d+$", "", task)
    return re.sub(r"(?<!^)(?=[A-Z])", "_", stem).lower()


def parse_demos(text: str) -> list[int]:
    values = []
    for part in text.split(","):
        part = part.strip()
        if not part.isdigit() or int(part) < 1:
            raise UsageError(f"--demos {text!r}: {part!r} is not a positive integer; give e.g. --demos 50,100,200")
        values.append(int(part))
    return list(dict.fromkeys(values))


def parse_train_seeds(text: str | None) -> tuple[int | None, ...]:
    if text is None:
        return (None,)
    seeds = []
    for part in text.split(","):
        part = part.strip()
        if not part.isdigit():
            raise UsageError(
                f"--train-seeds {text!r}: {part!r} is not a non-negative integer; give e.g. 1000,2000,3000"
            )
        seeds.append(int(part))
    return tuple(dict.fromkeys(seeds))


def parse_suites(text: str, snake: str) -> tuple[tuple[str, Path], ...]:
    """`standard`, `heldout` (the task's suite files) or suite files' paths, each once."""
    suites: dict[str, Path] = {}
    for part in (p.strip() for p in text.split(",")):
        if part in SUITE_NAMES:
            path = ROOT / "eval" / "suites" / SUITE_NAMES[part].format(snake=snake)
            if not path.is_file():
                raise UsageError(f"--suites {part}: no suite {path}")
            suites[part] = path
        elif part.endswith(".toml") and Path(part).is_file():
            suites[Path(part).stem] = Path(part)
        else:
            raise UsageError(
                f"--suites {text!r}: unknown suite {part!r}; valid choices: {', '.join(SUITE_NAMES)} or a suite file"
            )
    return tuple(suites.items())


def _default_path(folder: str, name: str, what: str, pattern: str) -> Path:
    path = ROOT / folder / name
    if not path.is_file():
        found = sorted(p.name for p in (ROOT / folder).glob(pattern))
        raise UsageError(f"no {what} {path}; found: {', '.join(found) or 'none'}")
    return path


def _check_config(config: Path, task: str, obs: str, policy: str) -> dict:
    try:
        data = json.loads(config.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise UsageError(f"config {config} is not readable JSON ({exc})") from None
    env = data.get("env") or {}
    policy_type = (data.get("policy") or {}).get("type")
    if policy_type != policy:
        raise UsageError(f"config {config} trains policy type {policy_type!r}, not --policy {policy}")
    if env.get("task") not in (None, task):
        raise UsageError(f"config {config} is for task {env['task']}, not --task {task}")
    if env.get("obs_type") not in (None, ENV_OBS_TYPE[obs]):
        raise UsageError(f"config {config} has env.obs_type {env['obs_type']!r}; --obs {obs} needs {ENV_OBS_TYPE[obs]}")
    return data


def _check_recipe(recipe: Path, task: str, obs: str) -> dict:
    if not recipe.is_file():
        raise UsageError(f"no recipe {recipe}")
    try:
        data = read_settings(recipe, "recipe", RECIPE_TABLE, RECIPE_KEYS)
    except KitbenchError as exc:
        raise UsageError(str(exc)) from None
    if "task" in data and canonical_task(data["task"]) != task:
        raise UsageError(f"recipe {recipe} records {data['task']}, not --task {task}")
    if data.get("obs_mode", "state") != obs:
        raise UsageError(f"recipe {recipe} records obs_mode {data.get('obs_mode')!r}, not --obs {obs}")
    return data


def _record_default(key: str):
    return next(f.default for f in dataclasses.fields(RecordConfig) if f.name == key)


def check_args(args: argparse.Namespace) -> Plan:
    """Every check that can fail before a file is written."""
    try:
        task = task_entry(args.task).name
    except KitbenchError as exc:
        raise UsageError(f"--task: {exc}") from None
    snake = task_snake(task)
    if args.obs not in OBS_CHOICES:
        raise UsageError(f"unknown --obs {args.obs!r}; valid choices: {', '.join(OBS_CHOICES)}")
    demos = parse_demos(args.demos)
    for flag, value in (("--policy", args.policy), ("--tag", args.tag)):
        if value is not None and not NAME.fullmatch(value):
            raise UsageError(f"{flag} {value!r} must be a name of letters, digits, '.', '_' or '-'")
    for flag, value, low in (
        ("--steps", args.steps, 1),
        ("--suite-episodes", args.suite_episodes, 1),
        ("--eval-batch-size", args.eval_batch_size, 1),
    ):
        if value is not None and value < low:
            raise UsageError(f"{flag} must be a positive integer, got {value}")
    if args.settle_steps is not None and args.settle_steps < 0:
        raise UsageError(f"--settle-steps must be a non-negative integer, got {args.settle_steps}")
    if args.action_noise is not None and not (math.isfinite(args.action_noise) and args.action_noise >= 0):
        raise UsageError(f"--action-noise must be a finite number >= 0, got {args.action_noise}")
    for flag, key, value in (
        ("--action-noise", "action_noise", args.action_noise),
        ("--noise-phases", "noise_phases", args.noise_phases),
        ("--settle-steps", "settle_steps", args.settle_steps),
    ):
        if value is not None and key not in RECIPE_KEYS:
            raise UsageError(f"{flag}: this kitbench's `record` has no {key} setting (kitbench {kitbench.__version__})")
    if args.control_mode is not None and args.control_mode not in CONTROL_MODES:
        raise UsageError(f"unknown --control-mode {args.control_mode!r}; valid choices: {', '.join(CONTROL_MODES)}")
    name = f"{snake}_{args.obs}"
    if args.config:
        config = Path(args.config)
        if not config.is_file():
            raise UsageError(f"no config {config}")
    else:
        config = ROOT / "policies" / f"{args.policy}_{name}.json"
        if not config.is_file():
            valid = sorted(c.name.removesuffix(f"_{name}.json") for c in config.parent.glob(f"*_{name}.json"))
            raise UsageError(f"unknown --policy {args.policy!r} (no {config}); valid choices: {', '.join(valid)}")
    config_data = _check_config(config, task, args.obs, args.policy)
    recipe = Path(args.recipe) if args.recipe else _default_path("datasets", f"{name}.toml", "recipe", "*.toml")
    recipe_data = _check_recipe(recipe, task, args.obs)
    env = config_data.get("env") or {}
    published = published_entry(config)
    recorded_mode = recipe_data.get("control_mode") or _record_default("control_mode")
    if args.control_mode is None and env.get("control_mode", recorded_mode) != recorded_mode:
        # a policy trained on one action space and run in another fails for no reason the table could show
        raise UsageError(
            f"config {config} has env.control_mode {env['control_mode']} but recipe {recipe} records "
            f"{recorded_mode}; pass --control-mode to record, train and evaluate in one of them"
        )
    workers = config_data.get("num_workers", 4)  # lerobot's default
    if not isinstance(workers, int) or workers < 0:
        raise UsageError(f"config {config} has num_workers {workers!r}; give a non-negative integer")
    _default_path("eval/suites", f"{snake}.toml", "suite", "*.toml")
    suites = parse_suites(args.suites, snake)
    for _, suite in suites:
        try:
            loaded = load_suite(suite)
        except KitbenchError as exc:
            raise UsageError(str(exc)) from None
        if loaded.task != task:
            raise UsageError(f"suite {suite} is for {loaded.task}, not --task {task}")
        if args.suite_episodes is not None and args.suite_episodes > len(loaded.seeds):
            raise UsageError(f"--suite-episodes {args.suite_episodes}: suite {suite} has {len(loaded.seeds)} seeds")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {out} is a file; give a folder")
    return Plan(
        task=task,
        snake=snake,
        obs=args.obs,
        demos=demos,
        policy=args.policy,
        config=config,
        recipe=recipe,
        suites=suites,
        out=out,
        steps=args.steps,
        control_mode=args.control_mode or recorded_mode,
        control_mode_flag=args.control_mode,
        config_has_env=bool(env),
        train_threads=run.train_threads(config, published.threads_on(False) if published else None),
        action_noise=args.action_noise,
        noise_phases=args.noise_phases,
        settle_steps=args.settle_steps,
        suite_episodes=args.suite_episodes,
        eval_batch_size=args.eval_batch_size,
        tag=args.tag,
        option_sets=parse_sweep(args.policy_option or [], config_data["policy"]["type"]),
        train_seeds=parse_train_seeds(args.train_seeds),
        overwrite=args.overwrite,
    )


def record_command(plan: Plan, demos: int, data: Path) -> list[str]:
    command = [str(BIN / "kitbench"), "record", str(plan.recipe), "--episodes", str(demos), "--out", str(data)]
    command.append("--overwrite")
    if plan.control_mode_flag is not None:
        command += ["--control-mode", plan.control_mode_flag]
    if plan.action_noise is not None:
        command += ["--action-noise", str(plan.action_noise)]
    if plan.noise_phases is not None:
        command += ["--noise-phases", plan.noise_phases]
    if plan.settle_steps is not None:
        command += ["--settle-steps", str(plan.settle_steps)]
    return command


def _recorded_episodes(data: Path) -> int | None:
    try:
        return json.loads((data / "meta" / "info.json").read_text()).get("total_episodes")
    except (OSError, json.JSONDecodeError):
        return None


def dataset_request(plan: Plan, run_dir: Path, demos: int) -> tuple[list[str], dict, bool]:
    """The recording command for the run, what identifies its recording, and whether the dataset already there is
    reused: the same command recorded it from the same recipe with this kitbench version (the recording settings
    alone omit the episode count and any recipe key kitbench does not yet store)."""
    data = run_dir / "data"
    command = record_command(plan, demos, data)
    request = {
        "command": command,
        "recipe_sha256": hashlib.sha256(plan.recipe.read_bytes()).hexdigest(),
        "kitbench_version": kitbench.__version__,
    }
    stamp = run_dir / "record_request.json"
    recorded = read_recording_settings(data)
    reused = (
        recorded is not None
        and stamp.is_file()
        and json.loads(stamp.read_text()) == {**request, "recording": recorded}
        and recorded.get("kitbench_version") == kitbench.__version__
        and recorded.get("control_mode") == plan.control_mode
        and _recorded_episodes(data) == demos
    )
    return command, request, reused


def ensure_dataset(plan: Plan, run_dir: Path, demos: int) -> tuple[list[str], bool]:
    """Record the run's demonstrations, or reuse the dataset already there (`dataset_request`). Returns the
    recording command and whether the data was reused."""
    data = run_dir / "data"
    command, request, reused = dataset_request(plan, run_dir, demos)
    if reused:
        return command, True
    stamp = run_dir / "record_request.json"
    stamp.unlink(missing_ok=True)
    run.run_logged(command, run_dir / "record.log")
    recorded = read_recording_settings(data)
    if recorded is None:
        raise run.CommandFailed(command, run_dir / "record.log", 0)  # exited 0 yet left no kitbench dataset
    stamp.write_text(json.dumps({**request, "recording": recorded}, indent=1) + "\n")
    return command, False


# The data stamp of a recording `ensure_dataset` will make again: no finished training was made on it.
RECORDED_AGAIN = "recorded again"


def training(plan: Plan, data: Path, policy_dir: Path, seed: int | None = None, data_stamp: str | None = None):
    """The training of `plan.config` on `data` into `policy_dir` (`data_stamp`: the recording's stamp, by default
    the one beside `data`)."""
    extra = (f"--env.control_mode={plan.control_mode_flag}",) if plan.control_mode_flag and plan.config_has_env else ()
    if data_stamp is None:
        stamp = data.parent / "record_request.json"
        data_stamp = stamp.read_text() if stamp.is_file() else ""
    return run.Training(plan.config, data, policy_dir, plan.train_threads, plan.steps, seed, extra, data_stamp)


def check_trainings(plan: Plan) -> None:
    """Before anything is recorded: a finished training in a run folder is neither trained again by another
    request nor left without the recording it was trained on, unless --overwrite (`run.FinishedTraining`)."""
    for demos in plan.demos:
        run_dir = plan.out / run_name(plan, demos)
        _, _, reused = dataset_request(plan, run_dir, demos)
        for seed in plan.train_seeds:
            stamp = None if reused else RECORDED_AGAIN
            run.check_replace(training(plan, run_dir / "data", policy_dir_of(plan, run_dir, seed), seed, stamp))


def train(plan: Plan, data: Path, policy_dir: Path, seed: int | None = None) -> dict:
    """Train (or reuse a checkpoint the same command trained on the same data): `kitbench.training.run.train`."""
    return run.train(training(plan, data, policy_dir, seed), progress=plan.progress, overwrite=plan.overwrite)


def eval_dir_name(suite_name: str, options: tuple[tuple[str, object], ...]) -> str:
    parts = [p for p in (suite_name if suite_name != "standard" else "", options_tag(options)) if p]
    return "_".join(["eval", *parts])


def evaluate(
    plan: Plan,
    train_dir: Path,
    policy_dir: Path,
    options: tuple[tuple[str, object], ...] = (),
    suite: tuple[str, Path] = ("standard", Path()),
) -> tuple[list[str], dict, bool]:
    """Score the checkpoint on `suite`, or reuse the report the same command wrote; (command, report, reused)."""
    eval_dir = policy_dir / eval_dir_name(suite[0], options)
    command = run.eval_command(
        train_dir,
        suite[1],
        eval_dir,
        control_mode=plan.control_mode,
        episodes=plan.suite_episodes,
        batch_size=plan.eval_batch_size,
        options=options,
    )
    report, reused = run.evaluate(command, eval_dir, policy_dir / run.TRAIN_STAMP)
    return command, report, reused


def machine() -> dict:
    return {
        "cpu_count": os.cpu_count(),
        "processor": platform.processor(),
        "platform": platform.platform(),
        "python": platform.python_version(),
    }


def now() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


def run_name(plan: Plan, demos: int) -> str:
    return f"{plan.snake}_{plan.obs}_d{demos}" + (f"_{plan.tag}" if plan.tag else "")


def check_run_folders(plan: Plan) -> None:
    """A run folder holds one recipe's recording and what was trained on it: the same --tag given to another
    recipe (the SO-101's and the Panda's of one task share a name) would record over that data."""
    for demos in plan.demos:
        stamp = plan.out / run_name(plan, demos) / "record_request.json"
        if not stamp.is_file():
            continue
        command = json.loads(stamp.read_text()).get("command", [])  # record_command's: the recipe third
        if len(command) > 2 and Path(command[2]).resolve() != plan.recipe.resolve():
            raise UsageError(
                f"{stamp.parent} holds a recording of {command[2]}, not {plan.recipe}; give this recipe another --tag"
            )


def policy_dir_of(plan: Plan, run_dir: Path, seed: int | None) -> Path:
    return run_dir / (plan.policy if seed is None else f"{plan.policy}_seed{seed}")


def one_run(plan: Plan, demos: int, reading: Reading, on_row=None) -> list[dict]:
    """Record (or reuse), train once per training seed, and score each checkpoint once per suite and option set:
    one row each (`on_row(row)` as each is made)."""
    started = now()
    reference_s = reading.seconds
    name = run_name(plan, demos)
    run_dir = plan.out / name
    data = run_dir / "data"
    print(f"[{name}] {demos} demonstrations -> {data}", flush=True)
    record, reused = ensure_dataset(plan, run_dir, demos)
    if reused:
        print(f"[{name}]   reusing the dataset recorded by the same command", flush=True)
    rows = []
    for seed in plan.train_seeds:
        policy_dir = policy_dir_of(plan, run_dir, seed)
        which = "" if seed is None else f", training seed {seed}"
        print(f"[{name}] training {plan.policy}{which} ({plan.config}); log {policy_dir / 'train.log'}", flush=True)
        trained = train(plan, data, policy_dir, seed)
        done = "reused the checkpoint trained by the same command" if trained["reused"] else "trained"
        after = trained.get("reference_after")  # absent from checkpoints stamped before it was measured
        machine_then = (
            f" (reference workload {after:.1f} s as it ended, {reference_s:.1f} s at this run's start)" if after else ""
        )
        print(
            f"[{name}]   {done}: {trained['steps']} steps in {trained['seconds'] / 60:.1f} min{machine_then}",
            flush=True,
        )
        shared = {"demos": demos, "started": started, "name": name, "data": data, "record": record, "reused": reused}
        for suite in plan.suites:
            for options in plan.option_sets:
                what = f" with {options_tag(options)}" if options else ""
                print(f"[{name}] evaluating on {suite[1]}{what}", flush=True)
                eval_cmd, report, _ = evaluate(plan, trained["dir"], policy_dir, options, suite)
                row = _row(plan, shared, trained, eval_cmd, report, options, seed, suite, reading)
                rows.append(row)
                if on_row is not None:
                    on_row(row)
    return rows


def _row(
    plan: Plan,
    shared: dict,
    trained: dict,
    eval_cmd: list[str],
    report: dict,
    options,
    seed: int | None = None,
    suite: tuple[str, Path] = ("standard", Path()),
    reading: Reading | None = None,
) -> dict:
    """One results row: the run's recording and training (`shared`, `trained`) and one evaluation of it."""
    demos, started, name, data = shared["demos"], shared["started"], shared["name"], shared["data"]
    record, reused = shared["record"], shared["reused"]
    policy_dir = policy_dir_of(plan, plan.out / name, seed)
    tag = "+".join(t for t in (plan.tag, options_tag(options)) if t) or None
    k, n = report["success"]["count"], report["episodes"]
    lo, hi = wilson_interval(k, n)
    recorded = read_recording_settings(data) or {}  # what the recipe and the flags came to
    qualifiers = [q for q in (f"seed {seed}" if seed is not None else "", suite[0], options_tag(options)) if q]
    return {
        "task": plan.task,
        "obs": plan.obs,
        "policy": plan.policy,
        "tag": tag,
        "run": name + (f" [{', '.join(qualifiers)}]" if qualifiers else ""),
        "policy_options": dict(options),
        "demos": demos,
        "train_seed": trained.get("seed") if seed is None else seed,
        "suite_name": suite[0],
        "params": trained["params"],
        "params_source": trained["params_source"],
        "train_steps": trained["steps"],
        "batch_size": trained["batch_size"],
        "train_device": trained["device"],
        "train_seconds": trained["seconds"],
        "train_loop_seconds": trained["loop_seconds"],
        "train_reused": trained["reused"],
        # the loop's rate where the log dates it: at a few steps start-up (imports, dataset, dataloader workers)
        # would dominate the wall clock
        "steps_per_s": trained["steps"] / (trained["loop_seconds"] or trained["seconds"]),
        "step_seconds": pace.step_seconds(policy_dir / "train.log"),
        "reference_seconds": None if reading is None else reading.seconds,
        "reference_seconds_after_training": trained.get("reference_after"),
        # the workload's share of its threads' time: below kitbench.training.reference.BUSY_SHARE the machine was busy
        "reference_share": None if reading is None else reading.share,
        "reference_share_after_training": trained.get("reference_after_share"),
        "success": {"count": k, "episodes": n, "rate": k / n if n else 0.0, "ci95": [lo, hi]},
        "criteria": {c: r["rate"] for c, r in report["criteria"].items()},
        "failure_categories": report["failure_categories"],
        "record": {
            "recipe": str(plan.recipe),
            "control_mode": plan.control_mode,
            "action_noise": recorded.get("action_noise", plan.action_noise),
            "noise_phases": recorded.get("noise_phases", plan.noise_phases),
            "settle_steps": recorded.get("settle_steps", plan.settle_steps),
            "reused": reused,
        },
        "config": str(plan.config),
        "suite": str(suite[1]),
        "commands": {
            "record": shlex.join(record),
            "train": run.shell_line(trained["command"], trained["env"]),
            "eval": shlex.join(eval_cmd),
        },
        "paths": {
            "data": str(data),
            "train": str(trained["dir"]),
            "report": str(policy_dir / eval_dir_name(suite[0], options) / REPORT_JSON),
        },
        "machine": machine(),
        "kitbench_version": kitbench.__version__,
        "lerobot_version": version("lerobot"),
        "started": started,
        "finished": now(),
    }


def pooled(rows: list[dict]) -> list[str]:
    """Per (policy, tag, demos): the success pooled over training seeds and suites, each suite's, the first two
    suites' gap, and each training seed's rate with their spread."""
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault((r["policy"], r.get("tag"), r["demos"]), []).append(r)
    lines = []
    for (policy, tag, demos), group in groups.items():

        def total(rs: list[dict]) -> tuple[int, int]:
            return sum(r["success"]["count"] for r in rs), sum(r["success"]["episodes"] for r in rs)

        def shown(k: int, n: int) -> str:
            lo, hi = wilson_interval(k, n)
            return f"{k}/{n} {k / n:.1%} ({lo:.1%}–{hi:.1%})"

        seeds = list(dict.fromkeys(r["train_seed"] for r in group))
        suites = list(dict.fromkeys(r["suite_name"] for r in group))
        lines.append(f"{policy}" + (f" [{tag}]" if tag else "") + f", {demos} demos, training seeds "
                     f"{', '.join(map(str, seeds))}, suites {', '.join(suites)}:")  # fmt: skip
        lines.append(f"  pooled: {shown(*total(group))}")
        by_suite = {s: total([r for r in group if r["suite_name"] == s]) for s in suites}
        for suite, (k, n) in by_suite.items():
            lines.append(f"  {suite}: {shown(k, n)}")
        if len(suites) >= 2:
            (k1, n1), (k2, n2) = by_suite[suites[0]], by_suite[suites[1]]
            lo, hi = newcombe_interval(k2, n2, k1, n1)  # first minus second
            lines.append(
                f"  gap {suites[0]} − {suites[1]}: {k1 / n1 - k2 / n2:+.1%} ({lo:+.1%} to {hi:+.1%}, Newcombe)"
            )
        per_seed = {s: total([r for r in group if r["train_seed"] == s]) for s in seeds}
        rates = {s: k / n for s, (k, n) in per_seed.items()}
        lines.append(
            "  per training seed: "
            + ", ".join(f"{s}: {shown(k, n)}" for s, (k, n) in per_seed.items())
            + (f"; spread {min(rates.values()):.1%}–{max(rates.values()):.1%}" if len(rates) > 1 else "")
        )
    return lines


def published_entry(config: Path) -> Published | None:
    """The config's published figures (policies/published.toml, read as `kitbench reproduce` reads them), if it has
    any."""
    return load_published().get(config.stem)


def print_cost(plan: Plan, reading: Reading) -> None:
    """What the run will do and, from the config's published figures, about how long it will take here."""
    reference_s = reading.seconds
    trainings = len(plan.demos) * len(plan.train_seeds)
    evaluations = trainings * len(plan.suites) * len(plan.option_sets)
    print(
        f"plan: {len(plan.demos)} recording(s) ({', '.join(map(str, plan.demos))} demos), {trainings} training(s) "
        f"(seeds {', '.join('config' if s is None else str(s) for s in plan.train_seeds)}), {evaluations} "
        f"evaluation(s) on {', '.join(name for name, _ in plan.suites)}; reference workload here: {reference_s:.1f} s"
    )
    if reading.busy:
        print(f"cost: the machine was busy as the run began: {reading.busy_note(int(plan.train_threads))}")
    entry = published_entry(plan.config)
    if entry is not None and entry.cpu:  # this bench trains the config as written, not as `--cpu` does
        print(f"cost: the published minutes are {entry.device}' with `kitbench reproduce --cpu`; not scaled here")
        return
    train_min = None if entry is None else entry.train_minutes_here(reference_s, plan.steps)
    if entry is None or train_min is None:
        print("cost: no published training time for this config to scale (policies/published.toml)")
        return
    eval_min = entry.eval_minutes_here(reference_s) or 0.0
    total = trainings * train_min + evaluations * eval_min
    print(
        f"cost: about {total / 60:.1f} h here: {train_min:.0f} min a training, {eval_min:.0f} min an evaluation "
        f"(published {entry.train_minutes} min at a reference of {entry.training_reference} s and "
        f"{'?' if entry.eval_minutes is None else entry.eval_minutes} min at {entry.reference_seconds} s); recordings "
        "not counted"
    )
    if pace.reference_misleads(plan.config):
        print(
            "cost: the reference workload is a state config's update and does not carry a camera config's minutes "
            "between machines (docs/learnability.md); `kitbench reproduce` times the config's own steps, and each "
            "training's progress says its time left"
        )


def table(rows: list[dict]) -> str:
    """The rows as plain aligned text, one line per run."""
    criteria = list(dict.fromkeys(c for r in rows for c in r["criteria"]))
    header = ["run", "demos", "policy", "params", "steps", "train min", "steps/s", "success", "95% CI", *criteria]
    header.append("failures")
    lines = []
    for r in rows:
        s = r["success"]
        failures = ", ".join(f"{c} {n}" for c, n in r["failure_categories"].items() if n) or "–"
        lines.append(
            [
                r["run"],
                str(r["demos"]),
                r["policy"],
                f"{r['params'] / 1e6:.2f}M",
                str(r["train_steps"]),
                f"{r['train_seconds'] / 60:.1f}",
                f"{r['steps_per_s']:.2f}",
                f"{s['count']}/{s['episodes']} {s['rate']:.0%}",
                f"{s['ci95'][0]:.0%}–{s['ci95'][1]:.0%}",
                *(f"{r['criteria'][c]:.0%}" if c in r["criteria"] else "–" for c in criteria),
                failures,
            ]
        )
    widths = [max(len(row[i]) for row in [header, *lines]) for i in range(len(header))]
    left = {0, 2, len(header) - 1}  # names read left-aligned, numbers right-aligned
    return "\n".join(
        "  ".join(
            cell.ljust(w) if i in left else cell.rjust(w) for i, (cell, w) in enumerate(zip(row, widths, strict=True))
        ).rstrip()
        for row in [header, *lines]
    )


def read_results(path: Path) -> list[dict]:
    if not path.is_file():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def plot(results: list[dict], task: str, obs: str, path: Path) -> None:
    """Success rate on the standard suite against demos with Wilson 95% error bars, one line per (policy, tag),
    pooled over training seeds; the latest row wins where a demo count and seed were run more than once."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    latest: dict[tuple, dict] = {}  # per (policy, tag, demos, training seed): the latest row on the standard suite
    for r in results:
        if r["task"] == task and r["obs"] == obs and r.get("suite_name", "standard") == "standard":
            latest[(r["policy"], r.get("tag"), r["demos"], r.get("train_seed"))] = r
    lines: dict[tuple[str, str | None], dict[int, dict]] = {}
    for (policy, tag, demos, _), r in latest.items():
        pool = lines.setdefault((policy, tag), {}).setdefault(demos, {"count": 0, "episodes": 0})
        pool["count"] += r["success"]["count"]
        pool["episodes"] += r["success"]["episodes"]
    for by_demos in lines.values():
        for demos, pool in by_demos.items():
            k, n = pool["count"], pool["episodes"]
            by_demos[demos] = {"success": {"rate": k / n, "ci95": list(wilson_interval(k, n))}}
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    demos_seen: set[int] = set()
    for (policy, tag), by_demos in sorted(lines.items(), key=lambda kv: (kv[0][0], kv[0][1] or "")):
        xs = sorted(by_demos)
        demos_seen.update(xs)
        successes = [by_demos[d]["success"] for d in xs]
        label = policy + (f" [{tag}]" if tag else "")
        ax.errorbar(xs, [s["rate"] for s in successes], yerr=error_bars(successes), marker="o", capsize=4, label=label)
    ax.set_xscale("log", base=2)  # demo counts are usually doubled from run to run
    ax.set_xticks(sorted(demos_seen), [str(d) for d in sorted(demos_seen)])
    ax.minorticks_off()
    ax.set_ylim(-0.02, 1.02)
    ax.yaxis.set_major_formatter(matplotlib.ticker.PercentFormatter(1.0))
    ax.set_xlabel("demonstrations")
    ax.set_ylabel("success rate (95% Wilson CI)")
    ax.set_title(f"{task} ({obs}): success vs demonstrations")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def publish(plan: Plan, row: dict) -> Path:
    """Append the run to results.jsonl and redraw the plot from everything recorded there."""
    results = plan.out / "results.jsonl"
    with results.open("a") as f:
        f.write(json.dumps(row) + "\n")
    png = plan.out / f"{plan.snake}_{plan.obs}_success_vs_demos.png"
    plot(read_results(results), plan.task, plan.obs, png)
    return png


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", required=True, help="e.g. LiftPegUpright-v1 or AssemblingKits-v1")
    parser.add_argument("--obs", default="state", help="state (default) or rgb")
    parser.add_argument("--demos", required=True, help="comma-separated demo counts, one run each, e.g. 50,100,200")
    parser.add_argument("--policy", default="act", help="policy type; picks policies/<policy>_<task>_<obs>.json")
    parser.add_argument("--steps", type=int, help="training steps (default: the config's)")
    parser.add_argument("--out", default="outputs/learnability", help="output folder (default outputs/learnability)")
    parser.add_argument("--control-mode", dest="control_mode", help="action space to record, train and evaluate in")
    parser.add_argument("--action-noise", dest="action_noise", type=float, help="passed to kitbench record")
    parser.add_argument(
        "--noise-phases", dest="noise_phases", help="passed to kitbench record (expert phases, comma-separated)"
    )
    parser.add_argument("--settle-steps", dest="settle_steps", type=int, help="passed to kitbench record")
    parser.add_argument(
        "--suite-episodes", dest="suite_episodes", type=int, help="score on the suite's first E seeds (default all)"
    )
    parser.add_argument(
        "--eval-batch-size",
        dest="eval_batch_size",
        type=int,
        default=1,
        help="environments stepped in lockstep per evaluation worker, one policy call for all (kitbench eval "
        "--batch-size; default 1)",
    )
    parser.add_argument("--tag", help="names a variant: run folders, results rows and plot lines carry it")
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace a finished training of another request (and the recording it trained on) in --out",
    )
    parser.add_argument("--config", help="lerobot-train config (default policies/<policy>_<task>_<obs>.json)")
    parser.add_argument("--recipe", help="kitbench record recipe (default datasets/<task>_<obs>.toml)")
    parser.add_argument(
        "--train-seeds", dest="train_seeds", help="train once per seed (lerobot-train --seed), e.g. 1000,2000,3000"
    )
    parser.add_argument(
        "--suites",
        default="standard",
        help="score each checkpoint on these: standard, heldout (eval/suites/<task>[_heldout].toml) or suite files",
    )
    parser.add_argument(
        "--policy-option",
        dest="policy_option",
        action="append",
        metavar="KEY=V1[,V2...]",
        help="score the checkpoint once per value (per combination, repeated): kitbench eval --policy-option",
    )
    return parser


def main() -> int:
    args = build_parser().parse_args()
    try:
        plan = check_args(args)
        check_run_folders(plan)
        if not plan.overwrite:
            check_trainings(plan)
    except (UsageError, run.FinishedTraining) as exc:
        print(f"learnability: error: {exc}", file=sys.stderr)
        return 2
    reading = read(int(plan.train_threads))
    print_cost(plan, reading)
    plan.out.mkdir(parents=True, exist_ok=True)
    rows: list[dict] = []
    pngs: list[Path] = []

    def on_row(row: dict) -> None:
        rows.append(row)
        pngs.append(publish(plan, row))
        s = row["success"]
        print(f"[{row['run']}] success {s['count']}/{s['episodes']} ({s['rate']:.0%})", flush=True)

    try:
        for demos in plan.demos:
            one_run(plan, demos, reading, on_row)
    except run.FinishedTraining as exc:  # made by another run into the same folder since this one checked
        print(f"learnability: error: {exc}", file=sys.stderr)
        return 2
    except run.CommandFailed as exc:
        if rows:
            print(table(rows))
        print(f"learnability: error: command failed with {exc}", file=sys.stderr)
        print(f"--- last lines of {exc.log} ---\n{run.log_tail(exc.log)}", file=sys.stderr)
        return 1
    print()
    print(f"{plan.task} · {plan.obs} · {plan.policy}" + (f" · {plan.tag}" if plan.tag else ""))
    print(table(rows))
    if len(plan.train_seeds) > 1 or len(plan.suites) > 1:
        print()
        print("\n".join(pooled(rows)))
    print(f"results: {plan.out / 'results.jsonl'}; plot: {pngs[-1] if pngs else None}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
