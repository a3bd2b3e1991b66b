"""Shipped LeRobot training configs and recording recipes: each config parses with lerobot's own parser, trains
offline, and points at the dataset a committed recipe writes, with matching observations and actions."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from kitbench.recording.recorder import load_recipe

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = sorted((ROOT / "policies").glob("*.json"))
RECIPES = {str(load_recipe(p).out): load_recipe(p) for p in sorted((ROOT / "datasets").glob("*.toml"))}


def test_every_task_has_act_and_diffusion_for_state_and_images():
    names = {p.stem for p in CONFIGS}
    for task in ("lift_peg_upright", "assembling_kits"):
        for kind in ("act", "diffusion"):
            for obs in ("state", "rgb"):
                assert f"{kind}_{task}_{obs}" in names


@pytest.mark.parametrize("path", CONFIGS, ids=[p.stem for p in CONFIGS])
def test_config_parses_with_lerobot_and_matches_its_recipe(path):
    import draccus
    from lerobot.configs.train import TrainPipelineConfig
    from lerobot.policies import ACTConfig, DiffusionConfig  # noqa: F401  (policy choices)

    import lerobot_env_kitbench  # noqa: F401  (the env choice, as lerobot-train discovers it)

    cfg = draccus.parse(TrainPipelineConfig, config_path=str(path), args=[])
    raw = json.loads(path.read_text())
    assert raw["policy"]["pretrained_backbone_weights"] is None  # no download at train time
    assert cfg.policy.push_to_hub is False and cfg.wandb.enable is False
    recipe = RECIPES.get(cfg.dataset.root)
    assert recipe is not None, f"{path.name}: no recipe in datasets/ writes {cfg.dataset.root}"
    assert cfg.env.task == recipe.task and cfg.env.control_mode == recipe.control_mode
    assert cfg.dataset.repo_id == recipe.dataset_repo_id
    assert (cfg.env.obs_type == "pixels_state") == (recipe.obs_mode != "state")
