"""`make demo` end to end on a tiny setting: datasets with video and MCAP, reports for expert and random."""

from __future__ import annotations

import json

import pytest

from kitbench.demo import DemoConfig, run_demo
from kitbench.registration import TASKS


def test_demo_records_and_evaluates_every_task(tmp_path, needs_vulkan):
    lines: list[str] = []
    results = run_demo(DemoConfig(out=tmp_path, episodes=1, eval_episodes=2, videos=1), say=lines.append)
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    assert set(results) == set(TASKS)
    for task, result in results.items():
        dataset = result["dataset"]
        ds = LeRobotDataset(f"kitbench/{task}", root=dataset)
        assert ds.num_episodes == 1 and any(k.startswith("observation.images.") for k in ds.meta.video_keys)
        assert (dataset / "mcap" / "episode_000000.mcap").is_file()
        for policy in ("expert", "random"):
            report = json.loads((tmp_path / "eval" / task / policy / "report.json").read_text())
            assert report["episodes"] == 2 and report["policy"] == policy
        assert results[task]["reports"]["random"]["success"]["count"] == 0
        assert len(results[task]["reports"]["expert"]["output"]["videos"]) == 1
        assert any(str(tmp_path / "eval" / task / "expert" / "report.md") in line for line in lines)


def test_demo_refuses_an_unknown_task(tmp_path):
    with pytest.raises(ValueError, match=r"unknown task.*Nope-v1.*valid choices"):
        run_demo(DemoConfig(out=tmp_path / "x", tasks=("Nope-v1",)))
    assert not (tmp_path / "x").exists()


def test_the_closing_loops_estimate_says_when_the_machine_was_busy_as_it_was_timed():
    from kitbench.demo import learning_loop
    from kitbench.training.reference import Reading

    quiet = learning_loop(cuda=False, reading=Reading(1.0, 1.0)).minutes
    busy = learning_loop(cuda=False, reading=Reading(1.0, 0.5)).minutes
    assert "busy" not in quiet
    assert busy.startswith(f"{quiet} (busy as it was timed: the reference workload had 50% of its "), busy
    assert busy.endswith("so its 1.0 s say little of this machine and minutes scaled by it read long)"), busy


def test_the_closing_loop_on_a_gpu_does_not_scale_a_figure_trained_on_a_cpu(monkeypatch):
    """The GPU's camera config publishes its held-out seeds trained on 2 CPU cores (`cpu = true`): their minutes and
    threads say nothing of a training on this GPU, so neither is carried over."""
    import os

    from kitbench.demo import learning_loop
    from kitbench.reproduce import load_published
    from kitbench.training.reference import Reading

    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    loop = learning_loop(cuda=True, reading=Reading(1.0, 1.0))
    entry = load_published()[loop.config]
    assert entry.cpu and entry.threads == 2
    assert loop.minutes == "its training time on this GPU not estimated (the published minutes are 2 CPU cores')"
    assert loop.published.endswith("min on 2 CPU cores")
    # the cores its 8 loader workers leave, as lerobot-train runs a GPU config, not the CPU trainings' 2
    assert loop.train_env["OMP_NUM_THREADS"] == str(max(1, (os.cpu_count() or 1) - 8))


def test_the_closing_loop_records_trains_and_scores_as_printed(tmp_path, monkeypatch, needs_vulkan):
    """The record -> train -> score commands the demo ends with, run as printed from a project folder (its recipes,
    configs and suites) on the CPU, with only a tiny size added to each."""
    import os
    import sys
    from pathlib import Path

    from kitbench.demo import learning_loop
    from kitbench.training.reference import Reading
    from tests import launch

    root = Path(__file__).resolve().parents[1]
    for folder in ("datasets", "policies", "eval"):
        (tmp_path / folder).symlink_to(root / folder)
    monkeypatch.chdir(tmp_path)
    loop = learning_loop(cuda=False, reading=Reading(1.0, 1.0))
    assert loop.config == "act_lift_peg_upright_rgb_96_cpu" and "min on 2 CPU cores" in loop.published
    assert "min of training here" in loop.minutes and "busy" not in loop.minutes  # scaled by the reference workload
    lines = loop.lines()
    assert any(
        line.endswith(" ".join([*(f"{k}={v}" for k, v in loop.train_env.items()), *loop.train])) for line in lines
    )
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled", **loop.train_env}
    env["PATH"] = f"{Path(sys.executable).parent}:{env.get('PATH', '')}"
    for command, tiny in (
        # one recording worker: the recipe's two would each start an interpreter of their own for one episode
        (loop.record, ["--episodes", "2", "--no-mcap", "--workers", "1"]),
        # no loader worker: spawning the config's is most of a two-step training's start
        (loop.train, ["--steps=2", "--save_freq=2", "--num_workers=0"]),
        (loop.score, ["--episodes", "2"]),
    ):
        # each a process of its own, forked from a server that imported kitbench and lerobot once (tests/launch.py)
        run = launch.run([*command, *tiny], text=True, env=env, timeout=900)
        assert run.returncode == 0, f"{command}: {run.stdout[-2000:]}{run.stderr[-2000:]}"
    report = json.loads((tmp_path / "outputs/eval/LiftPegUpright-v1").glob("*/report.json").__next__().read_text())
    assert report["episodes"] == 2 and report["policy"].startswith("lerobot:")
