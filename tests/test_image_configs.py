"""Every shipped image config (those for a GPU and those for 2 CPU cores) runs end to end on a CPU: record camera
demonstrations with its recipe's settings (the camera size included), train two steps with stock `lerobot-train`
(device overridden to the CPU), and score the checkpoint with `kitbench eval` on camera observations at the size
it was trained at."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from kitbench.recording.recorder import load_recipe, record
from tests import launch
from tests.lerobot_cli import BIN, OFFLINE, lerobot_train

ROOT = Path(__file__).resolve().parents[1]
IMAGE_CONFIGS = sorted(
    p
    for p in (ROOT / "policies").glob("*.json")
    if any(f["type"] == "VISUAL" for f in json.loads(p.read_text())["policy"].get("input_features", {}).values())
)
EPISODES = 2


@pytest.fixture(scope="module")
def datasets(tmp_path_factory):
    """One small camera dataset per recipe the image configs read, recorded as the recipe says."""
    base = tmp_path_factory.mktemp("rgb")
    out = {}
    for path in IMAGE_CONFIGS:
        root = json.loads(path.read_text())["dataset"]["root"]
        if root in out:
            continue
        data = base / Path(root).name
        recipe = load_recipe(ROOT / "datasets" / f"{Path(root).name}.toml", episodes=EPISODES, out=data, workers=1)
        record(recipe.replace(mcap=False), progress=False)
        out[root] = data
    return out


# A Diffusion image checkpoint re-planned every step runs its 28.6 M U-Net ten times a step: one AssemblingKits
# episode ran 13 minutes on 2 busy cores without finishing. The pipeline is what is tested, not the policy: 8 actions a
# prediction and 2 denoising steps run the U-Net 40x less often (8 x 10 / 2).
CHEAP_INFERENCE = {
    "diffusion": ["--policy-option", "n_action_steps=8", "--policy-option", "num_inference_steps=2"],
}


@pytest.mark.parametrize("path", IMAGE_CONFIGS, ids=[p.stem for p in IMAGE_CONFIGS])
def test_image_config_trains_on_a_cpu_and_its_checkpoint_is_scored(path, needs_vulkan, datasets, tmp_path):
    config = json.loads(path.read_text())
    from kitbench.reproduce import load_published

    published = load_published().get(path.stem)
    on_cpu = path.stem.endswith("_cpu")  # the configs sized for 2 CPU cores; the others are the GPU's
    assert config["policy"]["device"] == ("cpu" if on_cpu else "cuda"), path.stem
    if published:  # its figure was made where the config says it trains
        assert ("CPU" in published.extra["device"]) is on_cpu, (path.stem, published.extra["device"])
    data = datasets[config["dataset"]["root"]]
    out = tmp_path / "train"
    lerobot_train(
        path,
        data,
        out,
        tmp_path,
        "--policy.device=cpu",
        "--steps=2",
        "--batch_size=2",
        "--save_freq=2",
        "--env_eval_freq=0",
        "--log_freq=1",
    )
    checkpoint = out / "checkpoints" / "last" / "pretrained_model"
    saved = json.loads((checkpoint / "config.json").read_text())
    assert any(name.startswith("observation.images.") for name in saved["input_features"]), saved["input_features"]

    report = tmp_path / "eval"
    task = config["env"]["task"]
    score = launch.run(
        [
            str(BIN / "kitbench"),
            "eval",
            "--task",
            task,
            "--policy",
            f"lerobot:{out}",
            "--episodes",
            "1",
            "--obs-mode",
            "rgb",
            "--control-mode",
            config["env"]["control_mode"],
            "--out",
            str(report),
            *CHEAP_INFERENCE.get(config["policy"]["type"], []),
        ],
        capture_output=True,
        text=True,
        env=OFFLINE,
        timeout=900,
    )
    assert score.returncode == 0, score.stdout[-3000:] + score.stderr[-3000:]
    result = json.loads((report / "report.json").read_text())
    assert result["episodes"] == 1 and result["task"] == task
