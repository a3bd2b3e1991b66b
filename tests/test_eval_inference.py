"""How `kitbench eval` runs a trained policy: `--batch-size N` (episodes in lockstep, one policy call a step for the
batch), `--device`, and `--policy-option KEY=VALUE` (a checkpoint's inference settings for one run).

Batching never changes which seeds run or how a policy that acts one env at a time scores (bit for bit). A trained
network's batched actions equal its unbatched ones to float32 rounding (matrix kernels sum in another order for
another batch size: measured at most 8e-7 of a normalised action on a small ACT), which contact dynamics may carry
into the return (2.6% on one AssemblingKits seed over 200 steps); outcomes and lengths stay the same here."""

from __future__ import annotations

import functools
import json
import math
import subprocess
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

from kitbench.errors import KitbenchError
from kitbench.evaluation.config import EvalConfig
from kitbench.evaluation.report import without_timing
from kitbench.evaluation.runner import run_eval
from kitbench.evaluation.suite import adhoc_suite
from kitbench.recording.recorder import RecordConfig, record
from tests import launch
from tests.lerobot_cli import BIN, OFFLINE, lerobot_train, small_config

SEEDS = 4  # batches of 3: a full one and a shorter last one
# Camera images as small as a ResNet takes: the batching, not the pixels, is tested (a 128-pixel AssemblingKits run
# spent most of its time rendering and in the backbone).
CAMERA_SIZE = 64
CASES = [
    ("LiftPegUpright-v1", "state", "act"),
    ("LiftPegUpright-v1", "rgb", "act"),
    ("AssemblingKits-v1", "state", "act"),
    ("AssemblingKits-v1", "rgb", "act"),
    ("LiftPegUpright-v1", "state", "diffusion"),
]


@pytest.fixture(scope="module")
def checkpoints(tmp_path_factory):
    """A few training steps of a small policy per case, on two expert demonstrations: enough for a deterministic
    network whose actions differ from seed to seed. Each trained when a test first asks for it (`checkpoints[case]`),
    one recording per task and observation mode."""
    base = tmp_path_factory.mktemp("batch")

    @functools.cache
    def recorded(task: str, obs_mode: str) -> Path:
        root = base / f"{task}_{obs_mode}"
        cameras = {"camera_size": str(CAMERA_SIZE)} if obs_mode != "state" else {}
        record(
            RecordConfig.of(task, 2, root, obs_mode=obs_mode, control_mode="pd_ee_delta_pose", mcap=False, **cameras),
            progress=False,
        )
        return root

    class Trained(dict):
        def __missing__(self, case: tuple[str, str, str]) -> Path:
            task, obs_mode, policy = case
            root = recorded(task, obs_mode)
            info = json.loads((root / "meta/info.json").read_text())["features"]
            inputs = [n for n in info if n.startswith("observation.")]
            where = base / f"{task}_{obs_mode}_{policy}"
            where.mkdir()
            lerobot_train(small_config(root, where, inputs, policy, steps=4), root, where / "train", where)
            self[case] = where / "train"
            return self[case]

    return Trained()


def _eval(task, obs_mode, policy, out, batch_size, control_mode="pd_ee_delta_pose", **kwargs):
    suite = adhoc_suite(task, SEEDS, 1_000_000, obs_mode=obs_mode, control_mode=control_mode)
    return run_eval(EvalConfig.of(suite, policy, out, batch_size=batch_size, device="cpu", **kwargs), progress=False)


def _kitbench_eval(*args: str) -> subprocess.CompletedProcess:
    """`kitbench eval --task LiftPegUpright-v1 <args>`, offline, as a user runs it."""
    cmd = [str(BIN / "kitbench"), "eval", "--task", "LiftPegUpright-v1", *args]
    return launch.run(cmd, capture_output=True, text=True, env=OFFLINE, timeout=300)


def test_batches_of_policies_that_act_alone_score_exactly_as_unbatched(tmp_path):
    one = _eval("LiftPegUpright-v1", "state", "expert", tmp_path / "b1", 1, "pd_joint_target_delta_pos")
    for size in (2, 3, 8):  # a last batch shorter than the others; a batch larger than the suite
        batched = _eval(
            "LiftPegUpright-v1", "state", "expert", tmp_path / f"b{size}", size, "pd_joint_target_delta_pos"
        )
        assert without_timing(batched) == without_timing(one), size
        assert batched["timing"]["batch_size"] == size and batched["timing"]["device"] == "cpu"
    # the expert's episodes end at different steps, at success: finished episodes wait for their batch
    assert one["success"]["rate"] == 1.0 and len({e["length"] for e in one["per_episode"]}) > 1


# AssemblingKits on cameras repeats the code paths of two cases make test runs: the batched camera ACT of
# LiftPegUpright-v1-rgb-act and the AssemblingKits episodes of AssemblingKits-v1-state-act; at 200 steps an episode
# it took half this file's time (make test-all and CI run it too).
SLOW_CASES = {("AssemblingKits-v1", "rgb", "act")}
# One denoising step a prediction: the Diffusion re-plans every step as before, at a third of the U-Net's runs (the
# batching, not the policy, is tested).
CHEAP_DIFFUSION = (("num_inference_steps", 1),)


@pytest.mark.parametrize(
    ("task", "obs_mode", "policy"),
    [pytest.param(*c, id="-".join(c), marks=[pytest.mark.slow] if c in SLOW_CASES else []) for c in CASES],
)
def test_a_batched_network_scores_each_episode_as_unbatched(
    checkpoints, needs_vulkan, task, obs_mode, policy, tmp_path
):
    from kitbench.policies.lerobot_policy import LeRobotPolicy

    checkpoint = checkpoints[task, obs_mode, policy]
    spec = f"lerobot:{checkpoint}"
    cheap = {"policy_options": CHEAP_DIFFUSION} if policy == "diffusion" else {}
    one = _eval(task, obs_mode, spec, tmp_path / "b1", 1, **cheap)
    three = _eval(task, obs_mode, spec, tmp_path / "b3", 3, **cheap)
    assert [e["seed"] for e in three["per_episode"]] == [e["seed"] for e in one["per_episode"]]
    for a, b in zip(three["per_episode"], one["per_episode"], strict=True):
        assert (a["success"], a["failure"], a["length"]) == (b["success"], b["failure"], b["length"]), a["seed"]
    # Returns are not compared: float32 rounding in the batched kernels (below 1e-6 of an action) grows through
    # contacts into the return's later digits (2.6% on one AssemblingKits seed over 200 steps, outcome unchanged).
    if policy == "diffusion":  # seeded by its batch's first seed: the same command, the same report
        again = _eval(task, obs_mode, spec, tmp_path / "b3again", 3, **cheap)
        assert without_timing(again) == without_timing(three)

    # each row of a batched call is that episode's own action: rows are not mixed up, whatever the batch
    seeds = [1_000_000 + i for i in range(3)]
    cameras = {"sensor_configs": {"width": CAMERA_SIZE, "height": CAMERA_SIZE}} if obs_mode != "state" else {}
    envs = [gym.make(f"kitbench/{task}", obs_mode=obs_mode, control_mode="pd_ee_delta_pose", **cameras) for _ in seeds]
    resets = [env.reset(seed=s) for env, s in zip(envs, seeds, strict=True)]
    alone = []
    for env, seed, (obs, info) in zip(envs, seeds, resets, strict=True):
        single = LeRobotPolicy(str(checkpoint))
        single.reset(env, seed, obs, info)
        alone.append(single.act(obs))
    batch = LeRobotPolicy(str(checkpoint))
    batch.reset_batch(envs, seeds, [o for o, _ in resets], [i for _, i in resets])
    actions = batch.act_batch([o for o, _ in resets], [True] * 3)
    if policy == "act":
        np.testing.assert_allclose(actions, np.stack(alone), atol=1e-4)
        assert np.abs(actions[0] - actions[1]).max() > 1e-3  # different observations, different actions
    else:
        assert actions.shape == (3, *envs[0].action_space.shape) and np.isfinite(actions).all()
    for env in envs:
        env.close()


def test_cuda_without_cuda_is_refused_in_one_line_and_nothing_is_written(tmp_path):
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    out = tmp_path / "report"
    run = _kitbench_eval("--episodes", "2", "--device", "cuda", "--out", str(out))
    assert run.returncode == 2 and run.stderr.count("\n") == 1, run.stderr
    assert (
        "device 'cuda'" in run.stderr
        and "sees no CUDA device" in run.stderr
        and "valid choices: auto, cpu" in run.stderr
    )
    assert not out.exists()


@pytest.mark.parametrize(
    ("field", "value", "needle"),
    [
        ("batch_size", 0, "batch_size must be a positive integer, got 0"),
        ("batch_size", True, "batch_size must be a positive integer, got True"),
        ("device", "tpu", "unknown device 'tpu'; valid choices: auto, cpu, cuda"),
    ],
)
def test_bad_batch_settings_are_refused_before_anything_is_written(tmp_path, field, value, needle):
    suite = adhoc_suite("LiftPegUpright-v1", 2, 0)
    config = EvalConfig.of(suite, "zero", tmp_path / "report").replace(**{field: value})
    with pytest.raises(KitbenchError) as error:
        run_eval(config, progress=False)
    assert needle in str(error.value)
    assert not (tmp_path / "report").exists()


def test_the_lerobot_plugin_still_batches_its_envs(tmp_path):
    """`lerobot-eval --env.type=kitbench --eval.batch_size N` runs its own batch: unchanged by kitbench's."""
    from lerobot.envs.factory import make_env

    from lerobot_env_kitbench import KitbenchEnvConfig

    envs = make_env(KitbenchEnvConfig(task="LiftPegUpright-v1"), n_envs=3)["kitbench"][0]
    try:
        obs, _ = envs.reset(seed=[0, 1, 2])
        assert obs["agent_pos"].shape == (3, 8)
    finally:
        envs.close()


def test_help_names_the_flags():
    run = launch.run([str(BIN / "kitbench"), "eval", "--help"], capture_output=True, text=True, timeout=120)
    assert "--batch-size" in run.stdout and "--device" in run.stdout


def test_policy_options_change_inference_and_are_reported(checkpoints, tmp_path):
    from kitbench.policies.lerobot_policy import LeRobotPolicy

    checkpoint = checkpoints["LiftPegUpright-v1", "state", "act"]
    env = gym.make("kitbench/LiftPegUpright-v1", control_mode="pd_ee_delta_pose")

    def actions(options):
        policy = LeRobotPolicy(str(checkpoint), options=options)
        obs, info = env.reset(seed=7)
        policy.reset(env, 7, obs, info)
        return np.stack([policy.act(obs) for _ in range(4)])  # one observation, four steps: the env stands still

    plain = actions({})
    ensembled = actions({"temporal_ensemble_coeff": 0.01, "n_action_steps": 1})
    np.testing.assert_allclose(plain[0], ensembled[0], atol=1e-5)  # the first step has one chunk to average
    assert np.abs(plain[1:] - ensembled[1:]).max() > 1e-4  # later steps average the chunks predicted since
    env.close()

    spec = f"lerobot:{checkpoint}"
    suite = adhoc_suite("LiftPegUpright-v1", 2, 0, control_mode="pd_ee_delta_pose")
    options = (("temporal_ensemble_coeff", 0.01), ("n_action_steps", 1))
    report = run_eval(EvalConfig.of(suite, spec, tmp_path / "r", device="cpu", policy_options=options), progress=False)
    assert report["policy_options"] == {"temporal_ensemble_coeff": 0.01, "n_action_steps": 1}
    assert "`temporal_ensemble_coeff=0.01`" in (tmp_path / "r" / "report.md").read_text()
    assert "policy_options" not in _eval("LiftPegUpright-v1", "state", spec, tmp_path / "plain", 1)


def test_chunk_ensembling_weighs_each_step_as_acts_own_ensembler():
    """kitbench's ensembler (for Diffusion) and lerobot's ACT one give the same action at every step, chunks of
    several lengths and coefficients, a batch of episodes at once."""
    import torch
    from lerobot.policies.act.modeling_act import ACTTemporalEnsembler

    from kitbench.policies.ensemble import ChunkEnsembler

    generator = torch.Generator().manual_seed(0)
    for coeff, steps in ((0.01, 8), (0.3, 5), (-0.2, 3), (0.0, 1)):
        ours, theirs = ChunkEnsembler(coeff), ACTTemporalEnsembler(coeff, steps)
        theirs.reset()
        for _ in range(steps + 6):  # past the first chunk's end: every step averages `steps` chunks
            chunk = torch.randn(3, steps, 4, generator=generator)
            torch.testing.assert_close(ours.step(chunk), theirs.update(chunk.clone()), rtol=1e-5, atol=1e-6)


def test_a_diffusion_checkpoint_re_plans_every_step_and_averages_with_temporal_ensembling(checkpoints, tmp_path):
    """Diffusion's config has no ensembling; kitbench's option predicts a chunk every step from the observation
    window. A coefficient so large that only the oldest chunk counts acts exactly as plain Diffusion, which
    executes its first chunk open loop; 0.01 averages the chunks predicted since, so the actions differ."""
    from kitbench.policies.lerobot_policy import LeRobotPolicy

    checkpoint = str(checkpoints["LiftPegUpright-v1", "state", "diffusion"])
    env = gym.make("kitbench/LiftPegUpright-v1", control_mode="pd_ee_delta_pose")

    def actions(options, steps):
        policy = LeRobotPolicy(checkpoint, options=options)
        obs, info = env.reset(seed=7)
        policy.reset(env, 7, obs, info)  # the same noise for the first chunk either way
        return np.stack([policy.act(obs) for _ in range(steps)])  # one observation: the env stands still

    chunk = 5  # actions of each chunk: the test config executes one, its horizon allows up to 7
    plain = actions({"n_action_steps": chunk}, chunk)
    oldest = actions({"temporal_ensemble_coeff": 1e3, "n_action_steps": chunk}, chunk)
    averaged = actions({"temporal_ensemble_coeff": 0.01, "n_action_steps": chunk}, chunk + 3)  # nothing runs dry
    np.testing.assert_allclose(oldest, plain, atol=1e-6)
    np.testing.assert_allclose(averaged[0], plain[0], atol=1e-6)  # one chunk to average at the first step
    assert np.abs(averaged[1:chunk] - plain[1:]).max() > 1e-4
    env.close()

    suite = adhoc_suite("LiftPegUpright-v1", 3, 0, control_mode="pd_ee_delta_pose")
    options = (("temporal_ensemble_coeff", 0.01), *CHEAP_DIFFUSION)
    spec = f"lerobot:{checkpoint}"
    runs = [
        run_eval(
            EvalConfig.of(suite, spec, tmp_path / f"b{n}", device="cpu", batch_size=n, policy_options=options),
            progress=False,
        )
        for n in (1, 3)
    ]
    assert runs[0]["policy_options"] == {"temporal_ensemble_coeff": 0.01, "num_inference_steps": 1}
    outcomes = [[(e["seed"], e["success"], e["failure"], e["length"]) for e in r["per_episode"]] for r in runs]
    assert outcomes[0] == outcomes[1] and len(outcomes[0]) == 3


@pytest.mark.parametrize("value", ["fast", True, float("nan"), None])
def test_a_bad_ensembling_coefficient_for_diffusion_is_one_line(checkpoints, value):
    from kitbench.policies.lerobot_policy import LeRobotPolicy

    checkpoint = str(checkpoints["LiftPegUpright-v1", "state", "diffusion"])
    with pytest.raises(KitbenchError) as error:
        LeRobotPolicy(checkpoint, options={"temporal_ensemble_coeff": value})
    message = str(error.value)
    assert "\n" not in message and f"temporal_ensemble_coeff={value!r}: must be a finite number" in message


def test_a_diffusion_checkpoint_names_kitbench_ensembling_among_its_settings(checkpoints):
    from kitbench.policies.lerobot_policy import LeRobotPolicy

    checkpoint = str(checkpoints["LiftPegUpright-v1", "state", "diffusion"])
    with pytest.raises(KitbenchError, match="'temporal_ensemble_coef': the diffusion policy has no such setting") as e:
        LeRobotPolicy(checkpoint, options={"temporal_ensemble_coef": 0.01})
    assert "temporal_ensemble_coeff" in str(e.value).split("valid choices: ")[1].split(", ")


@pytest.mark.parametrize(
    ("option", "needle"),
    [
        ("temporal_ensemble_coef=0.01", "policy option 'temporal_ensemble_coef': the act policy has no such setting"),
        ("temporal_ensemble_coeff=0.01", "n_action_steps` must be 1 when using temporal ensembling"),
        ("n_action_steps", "policy option 'n_action_steps' is not KEY=VALUE"),
    ],
)
def test_a_bad_policy_option_is_refused_before_any_episode_runs(checkpoints, tmp_path, option, needle):
    out = tmp_path / "report"
    checkpoint = checkpoints["LiftPegUpright-v1", "state", "act"]
    run = _kitbench_eval(
        *("--episodes", "2", "--control-mode", "pd_ee_delta_pose", "--policy", f"lerobot:{checkpoint}"),
        *("--policy-option", option, "--out", str(out)),
    )
    assert run.returncode == 2 and run.stderr.count("\n") == 1 and needle in run.stderr, run.stderr
    assert not out.exists()


def test_policy_options_need_a_policy_with_settings(tmp_path):
    suite = adhoc_suite("LiftPegUpright-v1", 2, 0)
    config = EvalConfig.of(suite, "random", tmp_path / "r", policy_options=(("n_action_steps", 1),))
    with pytest.raises(KitbenchError, match=r"need a .*expert.* policy; 'random' has no settings") as error:
        run_eval(config, progress=False)
    assert "lerobot:<checkpoint>" in str(error.value) and "teleop:<device>" in str(error.value)
    assert not (tmp_path / "r").exists()
    # the expert's settings are its planner's: a policy's inference option is not one of them
    config = EvalConfig.of(suite, "expert", tmp_path / "r", policy_options=(("n_action_steps", 1),))
    with pytest.raises(KitbenchError, match="unknown expert option 'n_action_steps' for LiftPegUprightPlanner"):
        run_eval(config, progress=False)
    assert not (tmp_path / "r").exists()


def test_open_loop_bench_probes_a_diffusion_checkpoint_on_every_expert_state(checkpoints):
    """bench/open_loop.py on Diffusion (an observation window, no chunk from one observation): re-planned every
    step on the expert's states, one comparison per step of the expert's own episode, every figure a distance."""
    from bench.open_loop import measure, summarize
    from kitbench.policies.expert import ExpertPolicy
    from kitbench.recording.rollout import run_episode

    measured = measure(str(checkpoints["LiftPegUpright-v1", "state", "diffusion"]), "LiftPegUpright-v1", range(1))
    plain = run_episode(gym.make("kitbench/LiftPegUpright-v1", control_mode="pd_ee_delta_pose"), ExpertPolicy(), 0)
    rows = summarize(measured)
    assert sum(r["frames"] for r in rows) == plain.length
    assert {"approach", "grasp", "swing"} <= {r["phase"] for r in rows}
    for r in rows:
        assert all(math.isfinite(x) and x >= 0 for x in (*r["horizontal_mm"], *r["vertical_mm"], r["rotation_deg"]))


@pytest.mark.parametrize(
    "text,seeds",
    [("3", range(3)), ("5:8", range(5, 8)), ("1000004,1000013,7", [1000004, 1000013, 7])],
)
def test_open_loop_seeds_are_a_count_a_range_or_a_list(text, seeds):
    from bench.open_loop import describe_seeds, parse_seeds, seeds_json

    parsed = parse_seeds(text)
    assert list(parsed) == list(seeds)
    assert seeds_json(parsed) == ([seeds.start, seeds.stop] if isinstance(seeds, range) else seeds)
    assert describe_seeds(parsed) == (f"{seeds.start}..{seeds.stop - 1}" if isinstance(seeds, range) else text)


@pytest.mark.parametrize("text", ["0", "5:5", "-1:3", "3,-2", "a,b", "x"])
def test_open_loop_bad_seeds_name_the_forms(text):
    from bench.open_loop import parse_seeds

    with pytest.raises(KitbenchError, match=r"must be a count N, a range A:B .* or a list S1,S2"):
        parse_seeds(text)
