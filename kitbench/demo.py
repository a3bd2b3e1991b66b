"""The `make demo` job, end to end on a small default: for each task, record a few expert demonstrations (camera
video + MCAP logs) into a LeRobot dataset, then score the expert and the random policy on the task's short
evaluation suite, and say where everything is.
"""

from __future__ import annotations

import shlex
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from kitbench.config.checks import non_negative_int, positive_int
from kitbench.config.declare import setting, validate
from kitbench.errors import KitbenchError
from kitbench.registration import TASKS, canonical_task, make_env
from kitbench.shipped import ROOT
from kitbench.training.device import cuda_available
from kitbench.training.reference import Reading, read


@dataclass
class DemoConfig:
    # The output folder.
    out: Path = setting(Path("outputs/demo"))
    # Expert episodes recorded per task.
    episodes: int = setting(5, check=positive_int)
    # Episodes per policy evaluation (the short suites hold 10 seeds).
    eval_episodes: int = setting(10, check=positive_int)
    # Episodes filmed per expert evaluation.
    videos: int = setting(1, check=non_negative_int, cli=False)
    # Simulator processes.
    workers: int = setting(1, check=positive_int)
    # Only this task (repeatable; default every task).
    tasks: tuple[str, ...] = setting((), flag="--task", repeat=True)


def render_task_frames(out_dir: Path, seed: int = 0, tasks=tuple(TASKS)) -> list[Path]:
    """For each task: the 512x512 third-person view and every observation camera, after reset(seed)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for task in tasks:
        env = make_env(task, obs_mode="rgb", render_mode="rgb_array")
        try:
            obs, _ = env.reset(seed=seed)
            path = out_dir / f"{task}_render.png"
            frame = env.render()
            assert isinstance(frame, np.ndarray)
            Image.fromarray(frame).save(path)
            written.append(path)
            for camera, data in obs["sensor_data"].items():
                path = out_dir / f"{task}_{camera}.png"
                Image.fromarray(np.ascontiguousarray(data["rgb"])).save(path)
                written.append(path)
        finally:
            env.close()
    return written


def demo_suite(task: str, episodes: int):
    """The task's short suite (`eval/suites/*_short.toml` naming the task), else its first suite file, cut to
    `episodes`; a task that ships no suite gets `episodes` seeds from the evaluation range."""
    from kitbench.evaluation.suite import adhoc_suite, load_suite, shipped_suites

    files = shipped_suites(task, (Path.cwd(), ROOT))
    if not files:
        return adhoc_suite(task, episodes)
    short = [f for f in files if f.stem.endswith("_short")]
    return load_suite((short or files)[0]).first(episodes)


def run_demo(config: DemoConfig, say=print) -> dict:
    """Returns, per task, the dataset folder and the evaluation reports (policy -> report dict)."""
    from kitbench.evaluation.config import EvalConfig
    from kitbench.evaluation.output import summary_lines
    from kitbench.evaluation.runner import run_eval
    from kitbench.recording.recorder import RecordConfig, record

    tasks = tuple(canonical_task(t) for t in config.tasks) or tuple(TASKS)
    unknown = [t for t in tasks if t not in TASKS]
    if unknown:
        raise KitbenchError(f"unknown task(s) {', '.join(unknown)}; valid choices: {', '.join(TASKS)}")
    validate(config)
    out = Path(config.out)
    suites = {task: demo_suite(task, config.eval_episodes) for task in tasks}
    frames = render_task_frames(out / "frames", tasks=tasks)
    say(f"scene snapshots: {out / 'frames'} ({len(frames)} PNG files)")
    results = {}
    for task in tasks:
        dataset = out / "datasets" / task
        say(f"\n== {task}: recording {config.episodes} expert episodes (rgb + MCAP)")
        summary = record(
            RecordConfig.of(
                task=task,
                episodes=config.episodes,
                out=dataset,
                obs_mode="rgb",
                mcap=True,
                overwrite=True,
                workers=config.workers,
            ),
            progress=True,
        )
        for line in summary.lines(dataset):
            say(f"  {line}")
        say(f"  MCAP logs: {dataset / 'mcap'} (open in Foxglove)")
        reports = {}
        for policy, videos in (("expert", config.videos), ("random", 0)):
            report_dir = out / "eval" / task / policy
            shutil.rmtree(report_dir, ignore_errors=True)
            say(f"== {task}: evaluating {policy} on {suites[task].name} ({len(suites[task].seeds)} episodes)")
            reports[policy] = run_eval(
                EvalConfig.of(suites[task], policy, report_dir, workers=config.workers, videos=videos)
            )
            for line in summary_lines(reports[policy], report_dir):
                say(f"  {line}")
        results[task] = {"dataset": dataset, "reports": reports}
    first = tasks[0]
    kitbench = command_path("kitbench")
    say("\nnext:")
    say(f"  view an episode: {kitbench} view {out / 'datasets' / first}")
    for line in learning_loop(cuda_available()).lines():
        say(line)
    return results


def command_path(name: str) -> str:
    """How to run this environment's console script `name` as printed: its bare name when the shell finds this
    one, else its path (relative to the working folder when inside it), e.g. `.venv/bin/lerobot-train`."""
    here = Path(sys.executable).parent / name
    return name if shutil.which(name) == str(here) else shown(here)


def shown(path: Path) -> str:
    """`path` as printed in a command: relative to the working folder when inside it, else whole (a shipped file
    of an installed kitbench lies in its package)."""
    try:
        return str(path.relative_to(Path.cwd()))
    except ValueError:
        return str(path)


@dataclass(frozen=True)
class LearningLoop:
    """Record -> train -> score for one shipped config that learns on this machine, as commands that run as
    printed from the project folder."""

    config: str
    published: str  # its figure, in words
    minutes: str  # how long its training takes here, in words
    record: list[str]
    train: list[str]
    train_env: dict[str, str]
    score: list[str]
    reproduce: list[str]

    def lines(self) -> list[str]:
        train = " ".join([*(f"{k}={v}" for k, v in self.train_env.items()), shlex.join(self.train)])
        return [
            f"  learn from the demonstrations: {self.config} ({self.published}; {self.minutes}):",
            f"    1. record: {shlex.join(self.record)}",
            f"    2. train:  {train}",
            f"    3. score:  {shlex.join(self.score)}",
            f"    or all three, compared with the published figure: {shlex.join(self.reproduce)}",
        ]


# From the camera on both: the GPU's config, and the one sized for 2 CPU cores (bf16, batch 32, 2,500 steps, 96x96:
# 0.59x the 128x128 config's update, docs/studies/pixels-lift-peg-act.md; its figure: docs/results.md)
LOOP_CONFIG = {True: "act_lift_peg_upright_rgb", False: "act_lift_peg_upright_rgb_96_cpu"}


def learning_loop(cuda: bool, reading: Reading | None = None) -> LearningLoop:
    """The camera config for this machine: the GPU's where torch sees CUDA, else the one trained on 2 CPU cores."""
    from kitbench.reproduce import load_published
    from kitbench.training.precision import amp_flags
    from kitbench.training.run import train_threads

    name = LOOP_CONFIG[cuda]
    entry = load_published()[name]
    config = ROOT / "policies" / f"{name}.json"
    recipe = entry.recipe.relative_to(ROOT)
    train_dir = Path("outputs/train") / name
    suite = Path("eval/suites") / f"{entry.suites[0]}.toml"
    threads = train_threads(config, entry.threads_on(False))  # the config as written, on its own device
    published = f"{entry.rate:.1%} of {entry.episodes} published, {entry.train_minutes} min on {entry.device}"
    if entry.cpu:  # its figure trained on a CPU (`kitbench reproduce --cpu`); here it trains on the GPU
        minutes = f"its training time on this GPU not estimated (the published minutes are {entry.device}')"
    elif entry.training_reference:
        reading = read(int(threads)) if reading is None else reading
        minutes = f"about {entry.train_minutes_here(reading.seconds):.0f} min of training here"
        if reading.busy:  # a busy machine's estimate is not this machine's: say so beside it
            minutes += f" (busy as it was timed: {reading.busy_note(int(threads))})"
    else:
        minutes = "its training time here not estimated"
    precision = amp_flags(config)
    if precision:  # the published minutes were bf16's: say what this machine trains in instead
        minutes += "; in fp32, as this CPU computes no bf16"
    kitbench, train = command_path("kitbench"), command_path("lerobot-train")
    return LearningLoop(
        config=name,
        published=published,
        minutes=minutes,
        record=[kitbench, "record", str(recipe)],
        train=[train, f"--config_path={shown(config)}", f"--output_dir={train_dir}", *precision],
        train_env={"OMP_NUM_THREADS": threads},
        score=[kitbench, "eval", "--suite", str(suite), "--policy", f"lerobot:{train_dir}"],
        reproduce=[kitbench, "reproduce", name],
    )
