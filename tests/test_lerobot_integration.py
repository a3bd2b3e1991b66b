"""kitbench as a LeRobot citizen: record -> lerobot-train (shipped config, offline) -> evaluate the checkpoint
with kitbench and with lerobot-eval on the kitbench env plugin."""

from __future__ import annotations

import json
import math
import re
import sys
from pathlib import Path

import gymnasium as gym
import pytest

import kitbench  # noqa: F401
from kitbench.recording.recorder import RecordConfig, record
from tests import launch
from tests.lerobot_cli import BIN, OFFLINE, lerobot_train

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    base = tmp_path_factory.mktemp("lerobot")
    data = base / "lpu_state"
    # the shipped config's control mode (its in-training evaluation runs the env in it)
    config = RecordConfig.of(task="LiftPegUpright-v1", episodes=2, out=data, mcap=False, control_mode="pd_joint_pos")
    record(config, progress=False)
    out = base / "train"
    log = lerobot_train(
        ROOT / "policies/act_lift_peg_upright_state.json",
        data,
        out,
        base,
        "--steps=4",
        "--batch_size=4",
        "--save_freq=4",
        # evaluation during training on the kitbench env, two async envs, as the shipped configs do: in make test,
        # the async vector env's workers unpickling the plugin's env config (lerobot-eval's async case is slow)
        "--env_eval_freq=4",
        "--eval.n_episodes=2",
        "--eval.batch_size=2",
        "--eval.use_async_envs=true",
        "--log_freq=2",
    )
    assert re.search(r"success(:\s*|_rate=)\d", log), log[-3000:]  # the evaluation ran and reported success
    ckpt = out / "checkpoints" / "last" / "pretrained_model"
    assert (ckpt / "model.safetensors").is_file()
    assert json.loads((ckpt / "config.json").read_text())["pretrained_backbone_weights"] is None
    return ckpt


def test_env_plugin_is_discovered_by_lerobot(tmp_path):
    # a fork of the test server (tests/launch.py), which imports lerobot but not the plugin: the first check says so
    code = (
        "from lerobot.envs.configs import EnvConfig\n"
        "assert 'kitbench' not in EnvConfig.get_known_choices(), 'the plugin was imported before discovery'\n"
        "from lerobot.utils.import_utils import register_third_party_plugins\n"
        "register_third_party_plugins()\n"
        "cls = EnvConfig.get_choice_class('kitbench')\n"
        "cfg = cls(task='AssemblingKits-v1', obs_type='pixels_state')\n"
        "print(sorted(cfg.features_map.values()))\n"
    )
    script = tmp_path / "discover.py"
    script.write_text(code)
    out = launch.run([sys.executable, str(script)], capture_output=True, text=True, env=OFFLINE, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "observation.images.hand_camera" in out.stdout and "observation.environment_state" in out.stdout


def test_lerobot_env_speaks_lerobot_names(needs_vulkan):
    import gym_kitbench  # noqa: F401

    env = gym.make("gym_kitbench/LiftPegUpright-v1", obs_type="pixels_state")
    obs, info = env.reset(seed=0)
    params = {f"sensor_param.base_camera.{k}" for k in ("intrinsic_cv", "extrinsic_cv", "cam2world_gl")}
    assert set(obs) == {"agent_pos", "environment_state", "pixels", *params}
    assert obs["pixels"]["base_camera"].shape == (128, 128, 3)
    _, _, _, _, info = env.step(env.action_space.sample())
    assert info["is_success"] is False
    assert env.unwrapped.task_description.startswith("Pick up the peg")


def test_kitbench_eval_scores_the_trained_checkpoint(checkpoint, tmp_path):
    out = tmp_path / "report"
    result = launch.run(
        [
            sys.executable,
            "-m",
            "kitbench.cli",
            "eval",
            "--policy",
            f"lerobot:{checkpoint}",
            "--suite",
            "eval/suites/lift_peg_upright_short.toml",
            "--episodes",
            "2",
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=ROOT,
        env=OFFLINE,
    )
    assert result.returncode == 0, result.stderr
    report = json.loads((out / "report.json").read_text())
    assert report["policy"] == f"lerobot:{checkpoint}" and report["episodes"] == 2
    # the suite names pd_joint_delta_pos for the expert; the policy runs in the mode it was trained in
    assert report["suite"]["control_mode"] == "pd_joint_pos"
    assert all(e["length"] == 50 or e["success"] for e in report["per_episode"])
    assert (out / "report.md").is_file() and (out / "plots" / "success.png").is_file()


def test_kitbench_eval_refuses_another_control_mode_than_the_training_one(checkpoint):
    from kitbench.evaluation.config import EvalConfig
    from kitbench.evaluation.runner import validate
    from kitbench.evaluation.suite import adhoc_suite

    suite = adhoc_suite("LiftPegUpright-v1", 1, control_mode="pd_joint_delta_pos")
    with pytest.raises(ValueError, match=r"trained on pd_joint_pos actions.*--control-mode pd_joint_pos"):
        validate(
            EvalConfig.of(suite, f"lerobot:{checkpoint}", Path("unused"), origins={"control_mode": "command line"})
        )


def test_mismatched_policy_lists_expected_and_provided(checkpoint):
    from kitbench.policies.registry import make_policy
    from kitbench.recording.rollout import run_episode

    policy = make_policy(f"lerobot:{checkpoint}")
    with pytest.raises(ValueError) as err:
        run_episode(gym.make("kitbench/LiftPegUpright-v1", control_mode="pd_ee_delta_pos"), policy, seed=0)
    message = str(err.value)
    assert "mismatched: action" in message and "action[8]" in message and "action[4] (pd_ee_delta_pos)" in message
    with pytest.raises(ValueError, match=r"observation.environment_state\[7\].*observation.environment_state\[52\]"):
        run_episode(gym.make("kitbench/AssemblingKits-v1"), policy, seed=0)


def test_open_loop_bench_compares_the_checkpoint_with_the_expert_on_the_experts_states(checkpoint):
    """bench/open_loop.py: every step of the expert's episode is one comparison, filed under the phase the expert
    played, and the expert's episode is the one it plays without the probe (same length)."""
    from bench.open_loop import measure, summarize
    from kitbench.planning.lift_peg_upright_panda import LiftPegUprightPlanner
    from kitbench.policies.expert import ExpertPolicy
    from kitbench.recording.rollout import run_episode

    measured = measure(str(checkpoint), "LiftPegUpright-v1", range(3, 4))
    plain = run_episode(gym.make("kitbench/LiftPegUpright-v1", control_mode="pd_joint_pos"), ExpertPolicy(), seed=3)
    rows = summarize(measured)
    assert sum(r["frames"] for r in rows) == plain.length
    phases = [r["phase"] for r in rows]
    assert {"approach", "grasp", "swing"} <= set(phases)
    declared = LiftPegUprightPlanner.phases
    assert phases == sorted(phases, key=declared.index)
    for r in rows:  # a 4-step checkpoint is far off, but every figure is a distance
        assert all(math.isfinite(x) and x >= 0 for x in (*r["horizontal_mm"], *r["vertical_mm"], r["rotation_deg"]))
    assert max(r["horizontal_mm"][1] for r in rows) > 1.0


FIRST = 1_000_000  # the first seed of every lerobot-eval and kitbench eval run below


@pytest.fixture(scope="module")
def lerobot_eval(checkpoint, tmp_path_factory):
    """lerobot-eval of the checkpoint on LiftPegUpright-v1 through the plugin, seeds FIRST on: `lerobot_eval(batch_size,
    use_async)` runs batch_size episodes at once and returns its eval_info.json; a run is made once per module and
    shared by the tests that ask for the same one."""
    done: dict[tuple[int, bool], dict] = {}

    def evaluated(batch_size: int, use_async: bool) -> dict:
        if (batch_size, use_async) not in done:
            cwd = tmp_path_factory.mktemp(f"lerobot_eval_{batch_size}_{use_async}")
            cmd = [
                str(BIN / "lerobot-eval"),
                f"--policy.path={checkpoint}",
                "--policy.device=cpu",
                "--env.type=kitbench",
                "--env.task=LiftPegUpright-v1",
                "--env.control_mode=pd_joint_pos",
                f"--eval.n_episodes={batch_size}",
                f"--eval.batch_size={batch_size}",
                f"--eval.use_async_envs={str(use_async).lower()}",
                f"--output_dir={cwd / 'eval'}",
                f"--seed={FIRST}",
            ]
            run = launch.run(cmd, capture_output=True, text=True, env=OFFLINE, timeout=900, cwd=cwd)
            assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
            done[batch_size, use_async] = json.loads((cwd / "eval" / "eval_info.json").read_text())
        return done[batch_size, use_async]

    return evaluated


@pytest.mark.parametrize(
    "batch_size,use_async",
    # sync: the batch of 4 the comparison with kitbench eval below reads (one run for both); async: the plugin's env
    # in lerobot's async vector env, as the checkpoint's in-training evaluation runs it
    [(4, False), pytest.param(2, True, marks=pytest.mark.slow)],
    ids=["sync", "async"],
)
def test_lerobot_eval_runs_on_the_kitbench_env(lerobot_eval, needs_vulkan, batch_size, use_async):
    """Async vector-env workers unpickle the env config: its class must be importable at module level, and every
    sub-env must answer `task` and `task_description`."""
    info = lerobot_eval(batch_size, use_async)
    assert info["overall"]["n_episodes"] == batch_size


def test_lerobot_eval_at_batch_4_scores_as_kitbench_eval_does(lerobot_eval, checkpoint, tmp_path, needs_vulkan):
    """The same checkpoint on the same seeds: lerobot-eval (4 envs at once through the plugin) and kitbench eval
    agree episode by episode on success and on the summed reward, so scores from either tool compare."""
    info = lerobot_eval(4, False)
    assert info["overall"]["n_episodes"] == 4
    # eval_info.json keeps per-task lists, not the seeds; lerobot-eval seeds episode i of a batch with seed + i.
    (task,) = info["per_task"]
    metrics = task["metrics"]
    theirs = {
        FIRST + i: {"success": success, "sum_reward": reward}
        for i, (success, reward) in enumerate(zip(metrics["successes"], metrics["sum_rewards"], strict=True))
    }
    scored = [
        str(BIN / "kitbench"),
        "eval",
        "--task=LiftPegUpright-v1",
        f"--policy=lerobot:{checkpoint}",
        "--episodes=4",
        f"--seed={FIRST}",
        "--videos=0",
        f"--out={tmp_path / 'kitbench'}",
    ]
    run = launch.run(scored, capture_output=True, text=True, env=OFFLINE, timeout=900, cwd=tmp_path)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    ours = {e["seed"]: e for e in json.loads((tmp_path / "kitbench" / "report.json").read_text())["per_episode"]}
    assert sorted(theirs) == sorted(ours) == list(range(FIRST, FIRST + 4))
    for seed, episode in ours.items():
        assert theirs[seed]["success"] == episode["success"]
        assert theirs[seed]["sum_reward"] == pytest.approx(episode["episode_return"], rel=1e-4)
