"""`bench/train_levers.py`: a CPU training update of an image config, by parts and lever by lever, as lerobot-train
builds and runs it; bad arguments are one line (exit 2)."""

from __future__ import annotations

import functools
import json
import re
import sys
from pathlib import Path

import pytest

from kitbench.recording.recorder import load_recipe, record
from kitbench.training import precision
from tests import launch
from tests.lerobot_cli import OFFLINE

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "bench" / "train_levers.py"


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--levers", "bf17"], "'bf17' is not a lever"),
        (["--levers", "size"], "'size' is not a lever"),
        (["--steps", "1"], "--steps 1: give at least 2"),
        (["--config", "policies/nothing.json"], "no such file"),
        (["--config", "policies/act_lift_peg_upright_rgb.json", "--dataset", "a", "--dataset", "b"], "one per"),
    ],
)
def test_bad_arguments_are_one_line(args, message):
    run = launch.run([sys.executable, str(BENCH), *args], capture_output=True, text=True, cwd=ROOT, env=OFFLINE)
    assert run.returncode == 2 and message in run.stderr.strip().splitlines()[-1]


@pytest.fixture(scope="module")
def camera_data(tmp_path_factory):
    """Two episodes of the 96-pixel recipe both configs below train on, recorded once, when first asked for (after
    `needs_vulkan`, which a module fixture cannot wait for)."""

    @functools.cache
    def recorded() -> Path:
        data = tmp_path_factory.mktemp("levers") / "lpu"
        recipe = load_recipe(
            ROOT / "datasets" / "lift_peg_upright_rgb_contact_96.toml", episodes=2, out=data, workers=1
        )
        record(recipe.replace(mcap=False), progress=False)
        return data

    return recorded


@pytest.mark.parametrize(
    ("config", "levers"),
    [
        # the CPU configs train with use_amp: their parts run under autocast, and fp32 is a lever; each lever is a
        # process and a model of its own, so each path a lever takes is run once: amp off, the cameras resized,
        # NHWC on Diffusion's images (batch, steps, C, H, W). The 96-pixel CPU configs take the same paths as the
        # others at a fraction of their cost (the GPU Diffusion's U-Net and batch of 64 took minutes a lever here).
        ("act_lift_peg_upright_rgb_96_cpu", "baseline,fp32,size=64"),
        # Diffusion's path (and NHWC) in make test-all and CI: the bench's code path is the ACT case's
        pytest.param("diffusion_lift_peg_upright_rgb_96_cpu", "baseline,channels_last", marks=pytest.mark.slow),
    ],
)
def test_the_bench_times_the_parts_and_the_levers_of_a_real_update(needs_vulkan, camera_data, config, levers):
    data = camera_data()
    run = launch.run(
        [
            sys.executable,
            str(BENCH),
            "--config",
            f"policies/{config}.json",
            "--dataset",
            str(data),
            "--steps",
            "2",
            "--levers",
            levers,
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env=OFFLINE,
        timeout=900,
    )
    assert run.returncode == 0, run.stderr[-3000:]
    lines = run.stdout.splitlines()
    parts = next(line for line in lines if "parts of one update" in line)
    assert "optimizer" in parts and "data for a batch" in parts
    backbone = float(re.search(r"backbone fwd\+bwd ([0-9.]+) s", parts).group(1))
    assert backbone > 0, parts  # the camera images were found and run through the backbone
    for lever in levers.split(","):
        row = next(line for line in lines if line.strip().startswith(lever + " "))
        assert "s/update" in row and "samples/s" in row, row
    # the baseline is the update as kitbench trains it here: fp32 where the CPU computes no bf16, and says so
    autocast = json.loads((ROOT / "policies" / f"{config}.json").read_text())["policy"]["use_amp"]
    fp32_here = any("as kitbench trains here: training in fp32" in line for line in lines)
    assert fp32_here is (autocast and not precision.keep_cpu_amp()), lines[:3]
