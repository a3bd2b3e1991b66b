"""Datasets from any policy: `kitbench record --policy lerobot:<checkpoint>` (a trained policy's rollouts),
`--label expert` (DAgger: the expert's command at every state the policy reaches), and the dataset card written
with every dataset."""

from __future__ import annotations

import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import yaml

import kitbench  # noqa: F401  (registers the tasks)
from kitbench.errors import KitbenchError
from kitbench.policies.expert import ExpertPolicy
from kitbench.recording.recorder import RecordConfig, record
from tests import launch
from tests.lerobot_cli import BIN, OFFLINE, lerobot_train, small_config
from tests.test_recording import _columns

TASK = "LiftPegUpright-v1"


def _settings(root: Path) -> dict:
    return json.loads((root / "meta/kitbench_recording.json").read_text())


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    """A few training steps of a small ACT on two expert demonstrations in end-effector deltas."""
    base = tmp_path_factory.mktemp("policy")
    data = base / "data"
    record(RecordConfig.of(TASK, 2, data, control_mode="pd_ee_delta_pose", mcap=False), progress=False)
    inputs = ["observation.state", "observation.environment_state"]
    lerobot_train(small_config(data, base, inputs, steps=4), data, base / "train", base)
    return base / "train"


def test_the_card_describes_the_dataset_and_its_command_makes_it_again(tmp_path):
    out = tmp_path / "lpu"
    config = RecordConfig.of(TASK, 2, out, seed=4, control_mode="pd_joint_pos", settle_steps=3, action_noise=0.05)
    record(config, progress=False)
    text = (out / "README.md").read_text()
    header = yaml.safe_load(text.split("---")[1])
    assert {"LeRobot", "kitbench", TASK, "panda"} <= set(header["tags"]) and header["license"] == "apache-2.0"
    assert "task_categories" in header and header["configs"][0]["data_files"] == "data/*/*.parquet"
    assert "**`pd_joint_pos`**" in text and "with observations **`state`**" in text
    assert "- Episodes: 2 (" in text and "seeds 4–5" in text and "action noise 0.05" in text
    assert "as built for" not in text  # the Panda's is the reference build
    assert "| `observation.state` | float32 | (8,) |" in text and '"total_episodes": 2' in text
    command = text.split("- Made again by: `")[1].split("`")[0]
    assert command.startswith("kitbench record --task LiftPegUpright-v1 --episodes 2 --seed 4 ")
    again = tmp_path / "again"
    run = launch.run(
        [str(BIN / "kitbench"), *command.split()[1:-1], str(again)], capture_output=True, text=True, env=OFFLINE
    )
    assert run.returncode == 0, run.stderr[-2000:]
    assert _settings(again) == _settings(out)
    a, b = _columns(out), _columns(again)
    for name in ("action", "executed_action", "observation.state", "episode_seed"):
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)
    # a resumed recording's card counts what is there now
    record(
        RecordConfig.of(
            TASK, 3, out, seed=4, control_mode="pd_joint_pos", settle_steps=3, action_noise=0.05, resume=True
        ),
        progress=False,
    )
    assert "- Episodes: 3 (" in (out / "README.md").read_text()


def test_a_trained_policy_records_its_rollouts(checkpoint, tmp_path):
    from kitbench.policies.lerobot_policy import LeRobotPolicy

    out = tmp_path / "rollouts"
    spec = f"lerobot:{checkpoint}"
    summary = record(
        RecordConfig.of(TASK, 2, out, seed=10, control_mode="pd_ee_delta_pose", policy=spec), progress=False
    )
    assert summary.stored == 2 and _settings(out)["policy"] == spec
    columns = _columns(out)
    np.testing.assert_array_equal(columns["action"], columns["executed_action"])
    # the stored actions are the policy's: replayed from the seed, the policy acts them again
    env = gym.make(f"kitbench/{TASK}", control_mode="pd_ee_delta_pose")
    policy = LeRobotPolicy(str(checkpoint))
    obs, info = env.reset(seed=10)
    policy.reset(env, 10, obs, info)
    first = np.flatnonzero(columns["episode_index"].reshape(-1) == 0)
    for row in first[:10]:
        acted = np.clip(policy.act(obs), env.action_space.low, env.action_space.high)  # as the recorder stores it
        np.testing.assert_allclose(acted, columns["action"][row], atol=1e-5)
        obs, *_ = env.step(columns["executed_action"][row])
    env.close()


def test_a_trained_policy_in_another_control_mode_is_refused_naming_the_flag(checkpoint, tmp_path):
    out = tmp_path / "never"
    config = RecordConfig.of(TASK, 1, out, control_mode="pd_joint_delta_pos", policy=f"lerobot:{checkpoint}")
    with pytest.raises(KitbenchError) as error:
        record(config, progress=False)
    assert str(error.value) == (
        f"policy lerobot:{checkpoint} needs control_mode pd_ee_delta_pose (recording asks for pd_joint_delta_pos); "
        "record with --control-mode pd_ee_delta_pose"
    )
    assert not out.exists()


@pytest.mark.parametrize("policy", ["random", "checkpoint"])
def test_expert_labels_are_what_the_expert_commands_at_the_states_the_policy_reached(checkpoint, tmp_path, policy):
    spec = "random" if policy == "random" else f"lerobot:{checkpoint}"
    out = tmp_path / "dagger"
    record(
        RecordConfig.of(TASK, 2, out, seed=20, control_mode="pd_ee_delta_pose", policy=spec, label="expert"),
        progress=False,
    )
    assert _settings(out)["label"] == "expert" and "--label expert" in (out / "README.md").read_text()
    columns = _columns(out)
    assert np.abs(columns["action"] - columns["executed_action"]).max() > 0.05  # the policy is not the expert
    for episode, seed in ((0, 20), (1, 21)):
        rows = np.flatnonzero(columns["episode_index"].reshape(-1) == episode)
        env = gym.make(f"kitbench/{TASK}", control_mode="pd_ee_delta_pose")
        expert = ExpertPolicy()
        obs, info = env.reset(seed=seed)
        expert.reset(env, seed, obs, info)
        for row in rows:  # a fresh expert, re-planning along the executed trajectory, commands the stored labels
            label = np.clip(expert.act(obs), env.action_space.low, env.action_space.high)
            np.testing.assert_allclose(label, columns["action"][row], atol=1e-5, err_msg=f"row {row}")
            obs, *_ = env.step(columns["executed_action"][row])
        env.close()


@pytest.mark.parametrize(
    ("kwargs", "needle"),
    [
        ({"label": "oracle", "policy": "random"}, "unknown label 'oracle'; valid choices: expert"),
        ({"label": "expert"}, "label 'expert' labels policy 'expert' with itself; drop --label"),
        ({"policy": "lerobot:/nowhere"}, "no lerobot checkpoint at /nowhere"),
    ],
)
def test_bad_policy_and_label_settings_write_nothing(tmp_path, kwargs, needle):
    out = tmp_path / "never"
    with pytest.raises(KitbenchError) as error:
        record(RecordConfig.of(TASK, 1, out, **kwargs), progress=False)
    assert needle in str(error.value) and "\n" not in str(error.value)
    assert not out.exists()


@pytest.mark.parametrize("policy", ["expert", "checkpoint"])
def test_eval_saves_the_scored_episodes_as_a_dataset(checkpoint, tmp_path, policy):
    from kitbench.evaluation.config import EvalConfig
    from kitbench.evaluation.runner import run_eval
    from kitbench.evaluation.suite import adhoc_suite

    spec = "expert" if policy == "expert" else f"lerobot:{checkpoint}"
    suite = adhoc_suite(TASK, 3, 500, control_mode="pd_ee_delta_pose", settle_steps=2)
    data = tmp_path / "scored"
    report = run_eval(EvalConfig.of(suite, spec, tmp_path / "report", save_dataset=data), progress=False)
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    ds = LeRobotDataset("kitbench/test", root=data)
    assert ds.num_episodes == 3 and len(ds) == sum(e["length"] for e in report["per_episode"])
    stored = [json.loads(line) for line in (data / "meta/kitbench_episodes.jsonl").read_text().splitlines()]
    for kept, scored in zip(stored, report["per_episode"], strict=True):
        assert (kept["seed"], kept["length"]) == (scored["seed"], scored["length"])
        assert kept["success"] == scored["success_once"]
    settings = _settings(data)
    assert settings["policy"] == spec and settings["seeds"] == [500, 501, 502]
    assert "kitbench eval --task LiftPegUpright-v1 --seed 500 --episodes 3" in (data / "README.md").read_text()
    # the stored episodes are the scored ones: their executed actions replayed from the seeds end as scored
    columns = _columns(data)
    for episode, scored in enumerate(report["per_episode"]):
        env = gym.make(f"kitbench/{TASK}", control_mode="pd_ee_delta_pose")
        env.reset(seed=scored["seed"])
        for action in columns["executed_action"][columns["episode_index"].reshape(-1) == episode]:
            _, _, _, _, info = env.step(action)
        assert bool(info["success"]) == scored["success_at_end"]
        env.close()


@pytest.mark.parametrize(
    ("kwargs", "needle"),
    [
        ({"batch_size": 2}, "--save-dataset records episodes one at a time; drop --batch-size 2"),
        ({"existing": True}, "exists; pass --overwrite to replace it"),
    ],
)
def test_save_dataset_refusals_write_nothing(tmp_path, kwargs, needle):
    from kitbench.evaluation.config import EvalConfig
    from kitbench.evaluation.runner import run_eval
    from kitbench.evaluation.suite import adhoc_suite

    data = tmp_path / "scored"
    if kwargs.pop("existing", False):
        data.mkdir()
    config = EvalConfig.of(adhoc_suite(TASK, 2, 0), "zero", tmp_path / "report", save_dataset=data, **kwargs)
    with pytest.raises(KitbenchError) as error:
        run_eval(config, progress=False)
    assert needle in str(error.value)
    assert not (tmp_path / "report").exists() and not (data / "meta").exists()
