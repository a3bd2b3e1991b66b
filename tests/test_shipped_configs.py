"""Shipped LeRobot training configs and recording recipes: each config parses with lerobot's own parser, trains
offline, and points at the dataset a committed recipe writes, with matching observations and actions."""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from kitbench.envs.features import ENVIRONMENT_STATE, STATE
from kitbench.recording.card import STILL_CHECKED, held_still
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
    assert cfg.env.task == recipe.task and cfg.env.control_mode == recipe.env.control_mode
    assert cfg.env.robot == recipe.env.robot  # None: the task's default robot, in both
    assert cfg.dataset.repo_id == recipe.dataset_repo_id
    assert (cfg.env.obs_type == "pixels_state") == (recipe.env.obs_mode != "state")
    # the env the config builds renders the cameras as the recipe recorded them, at the size the policy reads
    assert (cfg.env.camera_size, cfg.env.camera_view) == (recipe.env.camera_size, recipe.env.camera_view)
    for name, feature in raw["policy"].get("input_features", {}).items():
        if feature["type"] == "VISUAL":
            channels, height, width = feature["shape"]
            assert cfg.env.features[f"pixels/{name.rpartition('.')[2]}"].shape == (height, width, channels)


LENGTH_SEEDS = 10  # episodes per recipe whose lengths the chunk check reads
# Initial states whose environment state joins those episodes' frames for the held-still check: a categorical
# entry (AssemblingKits' shape one-hot) is constant within an episode and 10 episodes do not draw all 20 shapes,
# while a constant of the task (a goal height) is the same in every initial state too.
RESET_SEEDS = 100


@cache
def _shortest_demo(
    task: str,
    control_mode: str,
    settle_steps: int,
    action_noise: float,
    noise_phases: tuple[str, ...] | None,
    first_seed: int,
    robot: str | None = None,
) -> tuple[int, dict[str, tuple[str, ...]]]:
    """The shortest successful episode among a recipe's first seeds, recorded as state (cameras do not change
    the physics, so an image recipe's episodes are as long), and per state vector (`observation.state`,
    `observation.environment_state`) the entries those episodes hold still (`kitbench.recording.card.held_still`)."""
    from kitbench.policies.expert import ExpertPolicy
    from kitbench.recording.features import dataset_features
    from kitbench.recording.rollout import run_episode
    from kitbench.registration import make_env

    env = make_env(task, obs_mode="state", control_mode=control_mode, robot_uids=robot)
    features = dataset_features(env)
    names = {key: list(features[key]["names"]) for key in STILL_CHECKED if key in features}
    lengths, states = [], {key: [] for key in names}
    for seed in range(first_seed, first_seed + LENGTH_SEEDS):
        episode = run_episode(
            env, ExpertPolicy(), seed, settle_steps=settle_steps, action_noise=action_noise, noise_phases=noise_phases
        )
        if episode.success:
            lengths.append(episode.length)
            for key in names:
                states[key] += [frame[key] for frame in episode.frames]
    if ENVIRONMENT_STATE in names:
        for seed in range(first_seed, first_seed + RESET_SEEDS):
            env.reset(seed=seed)
            states[ENVIRONMENT_STATE].append(env.unwrapped.environment_state())
    env.close()
    assert lengths, f"the {task} expert succeeded in none of seeds {first_seed}..{first_seed + LENGTH_SEEDS - 1}"
    std = {key: list(np.std(np.stack(values), axis=0)) for key, values in states.items()}
    return min(lengths), {key: tuple(held_still(names[key], std[key])) for key in names}


@pytest.mark.parametrize("path", CONFIGS, ids=[p.stem for p in CONFIGS])
def test_config_fits_the_data_its_recipe_writes(path):
    """Action chunks no longer than the demonstrations (a chunk past an episode's end is padding the policy
    learns nothing from, and lerobot-doctor flags it), and the env features the policy is evaluated on are the
    dataset's own."""
    import draccus
    from lerobot.configs.train import TrainPipelineConfig
    from lerobot.policies import ACTConfig, DiffusionConfig  # noqa: F401  (policy choices)

    import lerobot_env_kitbench  # noqa: F401
    from kitbench.envs.features import observation_features
    from kitbench.recording.features import dataset_features
    from kitbench.registration import make_env

    cfg = draccus.parse(TrainPipelineConfig, config_path=str(path), args=[])
    recipe = RECIPES[cfg.dataset.root]
    shortest, still = _shortest_demo(
        recipe.task,
        recipe.env.control_mode,
        recipe.demo.settle_steps,
        recipe.demo.action_noise,
        recipe.demo.noise_phases,
        recipe.demo.seed,
        recipe.env.robot,
    )
    policy = cfg.policy
    span = policy.chunk_size if policy.type == "act" else policy.horizon
    assert span <= shortest, f"{path.name}: {span} action steps per prediction, shortest demo {shortest}"
    assert policy.n_action_steps <= span
    # entries the demonstrations hold still must not be divided by their jitter (dataset card, "Held still")
    for key, entries in still.items():
        mode = policy.normalization_mapping.get(STILL_CHECKED[key])
        if entries and mode is not None:
            assert mode.value == "IDENTITY", f"{path.name}: {key} {entries} are held still, normalised {mode.value}"

    sensors = recipe.env.sensor_configs  # the recipe's camera size and view, where it sets them
    state_env = make_env(
        recipe.task,
        obs_mode="state",
        control_mode=recipe.env.control_mode,
        robot_uids=recipe.env.robot,
        **({"sensor_configs": sensors} if sensors else {}),
    )
    try:
        recorded = dataset_features(state_env)
        if recipe.env.obs_mode != "state":
            recorded.update(observation_features(state_env, recipe.env.obs_mode))
    finally:
        state_env.close()
    for key, name in cfg.env.features_map.items():
        assert name in recorded, f"{path.name}: env feature {key} ({name}) is not in the dataset"
        assert tuple(cfg.env.features[key].shape) == tuple(recorded[name]["shape"]), name
    wanted = {n for n in recorded if n.startswith("observation.")}
    assert wanted == set(cfg.env.features_map.values()) - {"action"}


@pytest.mark.parametrize("path", CONFIGS, ids=[p.stem for p in CONFIGS])
def test_state_and_cpu_configs_train_on_a_cpu_and_the_other_image_configs_say_they_want_a_gpu(path):
    raw = json.loads(path.read_text())
    assert raw["policy"]["device"] == ("cpu" if path.stem.endswith(("_state", "_cpu")) else "cuda")
    assert raw["eval"]["batch_size"] > 1 and raw["eval"]["use_async_envs"] is True
    if path.stem.endswith("_state"):
        assert 0 < raw["env_eval_freq"] <= raw["steps"]
    else:  # scored by `kitbench eval` on the GPU, batched, not by lerobot's two-env loop inside the budget
        assert raw["env_eval_freq"] == 0


@pytest.mark.parametrize("path", [p for p in CONFIGS if "_rgb" in p.stem], ids=lambda p: p.stem)
def test_image_configs_read_the_cameras_and_joints_not_the_object_pose(path):
    """lerobot-train feeds a policy every `observation.*` feature unless the config names its inputs, and a
    camera dataset also holds `observation.environment_state` (the objects' poses): an image config that left
    its inputs to lerobot would learn from the pose it is meant to see."""
    from kitbench.envs.features import IMAGES, observation_features
    from kitbench.registration import make_env

    raw = json.loads(path.read_text())
    inputs = raw["policy"]["input_features"]
    recipe = RECIPES[raw["dataset"]["root"]]
    sizes = recipe.env.sensor_configs  # the recipe's camera size, where it sets one
    env = make_env(
        recipe.task,
        obs_mode="state",
        control_mode=recipe.env.control_mode,
        robot_uids=recipe.env.robot,
        **({"sensor_configs": sizes} if sizes else {}),
    )
    try:
        recorded = observation_features(env, recipe.env.obs_mode)
    finally:
        env.close()
    cameras = {name for name in recorded if name.startswith(IMAGES)}
    assert ENVIRONMENT_STATE in recorded and ENVIRONMENT_STATE not in inputs
    assert set(inputs) == {STATE} | cameras
    assert inputs[STATE] == {"type": "STATE", "shape": list(recorded[STATE]["shape"])}
    for name in cameras:
        height, width, channels = recorded[name]["shape"]
        assert inputs[name] == {"type": "VISUAL", "shape": [channels, height, width]}
