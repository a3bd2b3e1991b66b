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
