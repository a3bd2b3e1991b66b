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
EPISODES = 1  # two training steps of a batch of 2 need one demonstration


@pytest.fixture(scope="module")
def datasets(tmp_path_factory):
    """One small camera dataset per recipe the image configs read, recorded as the recipe says when a test first asks
    for it (`datasets[root]`: after `needs_vulkan`)."""
    base = tmp_path_factory.mktemp("rgb")

    class Recorded(dict):
        def __missing__(self, root: str) -> Path:
            data = base / Path(root).name
            recipe = load_recipe(ROOT / "datasets" / f"{Path(root).name}.toml", episodes=EPISODES, out=data, workers=1)
            record(recipe.replace(mcap=False), progress=False)
            self[root] = data
            return data

    return Recorded()


# A Diffusion image checkpoint re-planned every step runs its 28.6 M U-Net ten times a step: one AssemblingKits
# episode ran 13 minutes on 2 busy cores without finishing. The pipeline is what is tested, not the policy: 8 actions a
# prediction and 2 denoising steps run the U-Net 40x less often (8 x 10 / 2). An ACT re-planned every step (those
# with temporal ensembling or n_action_steps 1) runs its ResNet on every camera every step: a whole chunk a
# prediction runs it chunk_size times less often.
def cheap_inference(policy: dict) -> list[str]:
    if policy["type"] == "diffusion":
        return ["--policy-option", "n_action_steps=8", "--policy-option", "num_inference_steps=2"]
    if policy["type"] == "act":
        chunk = f"n_action_steps={policy['chunk_size']}"
        return ["--policy-option", "temporal_ensemble_coeff=null", "--policy-option", chunk]
    return []


# Configs whose run repeats the code path of a twin that make test runs (`make test-all` and CI run them too). The
# three LiftPegUpright ones at 128 pixels for 2 CPU cores differ from their twin in robot or camera size only: the ACT
# CPU configs (use_amp, the `peg` view) are run by act_lift_peg_upright_so101_rgb_96_cpu, the Diffusion one by
# diffusion_lift_peg_upright_rgb_96_cpu, and the default size's path by act_lift_peg_upright_rgb,
# act_lift_peg_upright_fetch_rgb and diffusion_assembling_kits_rgb. act_lift_peg_upright_rgb_96_cpu is the Panda's
# twin of act_lift_peg_upright_so101_rgb_96_cpu (ACT, use_amp, the `peg` view at 96x96); test_demo's closing loop
# records, trains and scores it as well. diffusion_lift_peg_upright_rgb is diffusion_assembling_kits_rgb's GPU
# Diffusion (device cuda overridden, no amp, 128 pixels) on the recipe act_lift_peg_upright_rgb records and trains
# on. act_assembling_kits_rgb is the two-camera AssemblingKits ACT of its CPU twin with GPU settings (device cuda
# overridden, no amp: as act_lift_peg_upright_rgb) on the 128-pixel recipe that diffusion_assembling_kits_rgb trains on.
SLOW_TWIN = {
    "act_lift_peg_upright_rgb_cpu": "act_lift_peg_upright_so101_rgb_96_cpu",
    "act_lift_peg_upright_rgb_96_cpu": "act_lift_peg_upright_so101_rgb_96_cpu",
    "act_lift_peg_upright_so101_rgb_cpu": "act_lift_peg_upright_so101_rgb_96_cpu",
    "diffusion_lift_peg_upright_rgb_cpu": "diffusion_lift_peg_upright_rgb_96_cpu",
    "diffusion_lift_peg_upright_rgb": "diffusion_assembling_kits_rgb",
    "act_assembling_kits_rgb": "act_assembling_kits_rgb_cpu",
}
CASES = [pytest.param(p, id=p.stem, marks=[pytest.mark.slow] if p.stem in SLOW_TWIN else []) for p in IMAGE_CONFIGS]


def test_each_slow_config_has_its_twin_in_make_test():
    stems = {p.stem for p in IMAGE_CONFIGS}
    missing = {slow: twin for slow, twin in SLOW_TWIN.items() if {slow, twin} - stems or twin in SLOW_TWIN}
    assert not missing, f"a slow config without a shipped twin that make test runs: {missing}"


@pytest.mark.parametrize("path", CASES)
def test_image_config_trains_on_a_cpu_and_its_checkpoint_is_scored(path, needs_vulkan, datasets, tmp_path):
    config = json.loads(path.read_text())
    from kitbench.reproduce import load_published
    from kitbench.training.precision import amp_flags

    published = load_published().get(path.stem)
    on_cpu = path.stem.endswith("_cpu")  # the configs sized for 2 CPU cores; the others are the GPU's
    assert config["policy"]["device"] == ("cpu" if on_cpu else "cuda"), path.stem
    if published:  # its figure was made where the config says it trains, or on a CPU where its row says `cpu`
        assert not (on_cpu and published.cpu), path.stem
        assert ("CPU" in published.device) is (on_cpu or published.cpu), (path.stem, published.device)
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
        *amp_flags(path),  # fp32 on a CPU without bf16, as kitbench's own commands train there
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
            *cheap_inference(config["policy"]),
        ],
        capture_output=True,
        text=True,
        env=OFFLINE,
        timeout=900,
    )
    assert score.returncode == 0, score.stdout[-3000:] + score.stderr[-3000:]
    result = json.loads((report / "report.json").read_text())
    assert result["episodes"] == 1 and result["task"] == task
