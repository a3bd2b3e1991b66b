"""The `make demo` job, end to end on a small default: for each task, record a few expert demonstrations (camera
video + MCAP logs) into a LeRobot dataset, then score the expert and the random policy on the task's short
evaluation suite, and say where everything is.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from kitbench.errors import KitbenchError
from kitbench.registration import TASKS, make_env

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class DemoConfig:
    out: Path = Path("outputs/demo")
    episodes: int = 5  # recorded per task
    eval_episodes: int = 10  # per policy and task (the short suites hold 10 seeds)
    videos: int = 1  # filmed per expert evaluation
    workers: int = 1
    tasks: tuple[str, ...] = tuple(TASKS)


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
    from kitbench.evaluation.runner import EvalConfig, run_eval, summary_lines
    from kitbench.recording.recorder import RecordConfig, record

    unknown = [t for t in config.tasks if t not in TASKS]
    if unknown:
        raise KitbenchError(f"unknown task(s) {', '.join(unknown)}; valid choices: {', '.join(TASKS)}")
    out = Path(config.out)
    suites = {task: demo_suite(task, config.eval_episodes) for task in config.tasks}
    frames = render_task_frames(out / "frames", tasks=config.tasks)
    say(f"scene snapshots: {out / 'frames'} ({len(frames)} PNG files)")
    results = {}
    for task in config.tasks:
        dataset = out / "datasets" / task
        say(f"\n== {task}: recording {config.episodes} expert episodes (rgb + MCAP)")
        summary = record(
            RecordConfig(
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
                EvalConfig(suites[task], policy, report_dir, workers=config.workers, videos=videos)
            )
            for line in summary_lines(reports[policy], report_dir):
                say(f"  {line}")
        results[task] = {"dataset": dataset, "reports": reports}
    say("\nnext:")
    first = config.tasks[0]
    say(
        f'  load a dataset:  python -c "from lerobot.datasets.lerobot_dataset import LeRobotDataset; '
        f"print(LeRobotDataset('kitbench/{first}', root='{out / 'datasets' / first}'))\""
    )
    say(f"  view an episode: kitbench view {out / 'datasets' / first}")
    recipes = sorted(p.name for p in (ROOT / "datasets").glob("*.toml"))
    configs = sorted(p.name for p in (ROOT / "policies").glob("*.json"))
    if recipes:
        say(f"  record more:     kitbench record datasets/{recipes[0]}   (recipes: {', '.join(recipes)})")
    if configs:
        say(f"  train:           lerobot-train --config_path=policies/{configs[0]}   (configs: {', '.join(configs)})")
    return results
