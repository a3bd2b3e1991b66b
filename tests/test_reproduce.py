"""`kitbench reproduce`: a shipped config recorded, trained and scored end to end at a tiny scale, its figure compared
with the stated published interval (exit 0 inside, 3 outside); every published figure names a shipped config and
the recipe that writes its dataset; bad input is one line with nothing written."""

from __future__ import annotations

import functools
import json
import os
import re
from pathlib import Path

import numpy as np
import pytest

from kitbench import cli
from kitbench.recording.recorder import load_recipe
from kitbench.reproduce import PUBLISHED, load_published
from kitbench.training.reference import Reading

ROOT = Path(__file__).resolve().parents[1]
CONFIG = "act_lift_peg_upright_state"
SEED = load_published()[CONFIG].seeds[0]  # reproduce's default: the first training seed the figure pools


def test_every_published_figure_names_a_shipped_config_and_recipe_and_every_state_config_has_one():
    published = load_published()
    state_configs = {p.stem for p in (ROOT / "policies").glob("*_state.json")}
    assert state_configs <= set(published)
    for name, entry in published.items():
        assert (ROOT / "policies" / f"{name}.json").is_file() and entry.recipe.is_file()
        assert 0 <= entry.success <= entry.episodes and entry.interval[0] <= entry.rate <= entry.interval[1]
        assert all((ROOT / "eval" / "suites" / f"{s}.toml").is_file() for s in entry.suites)
        config = json.loads((ROOT / "policies" / f"{name}.json").read_text())
        assert config["steps"] == entry.steps
        # the figure was made on what the recipe writes, and that is what the config trains on
        assert str(load_recipe(entry.recipe).out) == config["dataset"]["root"], name


def _published(tmp_path: Path, seed_success: list[int], seed_episodes: list[int], step: float | None = None) -> Path:
    """The config's published entry, scored on both suites, with stand-in training seeds' figures (and a stand-in
    step time, `step`)."""
    text = PUBLISHED.read_text()
    start = text.index(f"[{CONFIG}]")
    end = text.index("\n[", start)
    entry = text[start:end]
    for key, values in (("seed_success", seed_success), ("seed_episodes", seed_episodes)):
        entry, replaced = re.subn(rf"(?m)^{key} = \[.*\]$", f"{key} = {values}", entry)
        assert replaced == 1, f"no {key} line in the [{CONFIG}] entry"
    entry = re.sub(r"(?m)^step_seconds = .*\n", "", entry)  # the row's own, if any: the stand-in's or none
    if step is not None:
        entry = entry.replace("\nreference_seconds =", f"\nstep_seconds = {step}\nreference_seconds =", 1)
    path = tmp_path / f"published-{sum(seed_success)}.toml"
    path.write_text(
        entry.replace('suites = ["lift_peg_upright"]', 'suites = ["lift_peg_upright", "lift_peg_upright_heldout"]')
    )
    return path


def _no_loader_workers(train_command, *args, **kwargs) -> list[str]:
    return [*train_command(*args, **kwargs), "--num_workers=0"]


def test_reproduce_runs_end_to_end_and_compares_with_where_a_new_seed_lands(
    tmp_path, needs_vulkan, capsys, monkeypatch
):
    from kitbench.training import pace, reference, run

    # the machine's reference workload and the config's own steps cut to a few: that they are timed, not their
    # figures, is the point here
    monkeypatch.setattr(reference, "WARMUP", 1)
    monkeypatch.setattr(reference, "STEPS", 2)
    monkeypatch.setattr(pace, "PROBE_STEPS", 2)
    monkeypatch.setattr(pace, "WINDOW", 1)
    # loading in the training process: spawning the config's loader workers is most of a tiny lerobot-train's start
    without_workers = functools.partial(_no_loader_workers, run.train_command)
    for module in (run, pace):
        monkeypatch.setattr(module, "train_command", without_workers)
    out = tmp_path / "run"
    argv = ["reproduce", CONFIG, "--steps", "2", "--demos", "2", "--eval-episodes", "2", "--out", str(out)]
    # three training seeds at 50% of 4: a 4-episode run lands anywhere
    assert cli.main([*argv, "--published", str(_published(tmp_path, [2, 2, 2], [4, 4, 4], step=0.05))]) == 0
    captured = capsys.readouterr()
    printed = captured.out
    result = json.loads((out / f"seed{SEED}" / "reproduce.json").read_text())
    assert result["episodes"] == 4 and result["inside"] is True  # two seeds of each of the two suites
    assert result["verdict"] == "none" and f"{CONFIG}: {result['success']}/4 = " in printed
    assert "a new training seed scored on 4 episodes is expected at 0.0%–100.0%" in printed
    assert "no verdict: at 95% a new training seed scored on 4 episodes may land anywhere" in printed
    assert f"train {CONFIG}: 2/2" in captured.err  # the training's progress, as lerobot-train made it
    assert (out / f"seed{SEED}" / "eval_lift_peg_upright_heldout" / "report.json").is_file()
    assert "--steps=2" in result["train_command"] and f"--seed={SEED}" in result["train_command"]
    assert result["reference_seconds"] > 0 and result["reference_seconds_after_training"] > 0
    # the published row keeps its step time, so the config's own steps were timed here first, into the scratch
    assert f"timing 2 steps of lerobot-train here (its log: {out / f'seed{SEED}' / pace.PROBE_LOG})" in printed
    assert result["probe_step_seconds"] > 0 and "step:2 " in (out / f"seed{SEED}" / pace.PROBE_LOG).read_text()
    assert f"a step {result['probe_step_seconds']:.3f} s here, lerobot-train's own timing" in printed
    assert sorted(p.name for p in (out / f"seed{SEED}").iterdir() if p.is_dir()) == sorted(
        ["train", "eval_lift_peg_upright", "eval_lift_peg_upright_heldout"]
    )

    # the recording and the training are reused, not made again; a figure the run cannot reach exits 3
    always = [1000, 1000, 1000] if result["success"] < 4 else [0, 0, 0]
    status = cli.main([*argv, "--published", str(_published(tmp_path, always, [1000, 1000, 1000], step=0.05))])
    printed = capsys.readouterr().out
    assert status == 3 and "what the published runs predict" in printed
    assert "reused the checkpoint the same command trained" in printed and "timing" not in printed
    assert "expected training time" not in printed  # nothing left to expect
    # the readings the training had, not the ones taken the day it is reused
    again = json.loads((out / f"seed{SEED}" / "reproduce.json").read_text())
    for key in ("reference_seconds", "reference_share", "probe_step_seconds"):
        assert again[key] == result[key], key


def test_the_verdict_counts_the_spread_between_training_seeds():
    """The report behind the issue: 189/200 against three training seeds at 97.0%, 97.0% and 98.0% of 200 (pooled
    97.3%, 95.7-98.4%) is a draw a new training seed can make, though it is outside the pooled interval."""
    from kitbench.evaluation.stats import prediction_interval

    low, high = prediction_interval([194, 194, 196], [200, 200, 200], 200)
    assert low <= 189 / 200 <= high and low > 0.85
    # the same figure from seeds that disagree with each other predicts a wider spread
    wide = prediction_interval([170, 194, 220 - 0], [200, 200, 220], 200)
    assert wide[0] < low
    # a single published run: its own sampling error and the new run's, no spread to estimate
    single = prediction_interval([98], [100], 100)
    assert 0.90 < single[0] < 0.95 and single[1] == 1.0


def test_a_figure_at_0_or_100_percent_leaves_a_new_seed_room():
    """At 0/200 (act_assembling_kits_rgb's selection seed) or 600/600 (act_lift_peg_upright_fetch_state's three
    seeds) the published rate's own sampling error is zero: an interval built on it alone called 1/200 "above" and
    199/200 "below". Built on the rate the runs share, it covers a new run at its 95% where the true rate is 2%
    or 98% (one published run and the new one of 100 episodes each), which that one did 84% of the time."""
    from scipy import stats

    from kitbench.evaluation.stats import prediction_interval
    from kitbench.reproduce import judgement

    none = prediction_interval([0], [200], 200)
    assert none[0] == 0.0 and 0.005 <= none[1] < 0.05
    assert judgement(1 / 200, none) == "consistent" and judgement(20 / 200, none) == "above"
    every = prediction_interval([200, 200, 200], [200, 200, 200], 200)
    assert every[1] == 1.0 and 0.9 < every[0] <= 199 / 200
    assert judgement(199 / 200, every) == "consistent" and judgement(0.8, every) == "below"

    n = 100
    counts = np.arange(n + 1)
    for rate in (0.02, 0.98):
        mass = stats.binom.pmf(counts, n, rate)
        intervals = [prediction_interval([int(c)], [n], n) for c in counts]
        covered = sum(
            w * mass[(counts / n >= lo - 1e-12) & (counts / n <= hi + 1e-12)].sum()
            for w, (lo, hi) in zip(mass, intervals, strict=True)
        )
        assert covered >= 0.94, (rate, covered)


def test_seeds_spread_so_widely_that_nothing_could_fall_outside_give_no_verdict():
    """diffusion_lift_peg_upright_rgb's held-out seeds (80, 74 and 41 of 100) leave a new seed anywhere in [0, 1]
    at 95%: a run there is neither consistent nor not, and says so instead of passing whatever it scores."""
    from kitbench.evaluation.stats import prediction_interval
    from kitbench.reproduce import judgement

    wide = prediction_interval([80, 74, 41], [100, 100, 100], 100)
    assert wide == (0.0, 1.0)
    assert judgement(0.05, wide) == judgement(0.95, wide) == "none"
    narrow = prediction_interval([87, 93, 92], [100, 100, 100], 100)
    assert judgement(0.90, narrow) == "consistent" and judgement(0.41, narrow) == "below"
    assert judgement(1.0, (0.2, 0.9)) == "above"


@pytest.mark.parametrize(
    "args,message",
    [
        (
            ["act_nothing"],
            "unknown config 'act_nothing'; valid choices: act_assembling_kits_rgb, act_assembling_kits_state",
        ),
        ([CONFIG, "--steps", "0"], "steps must be a positive integer, got 0"),
        ([CONFIG, "--seed", "-1"], "seed must be a non-negative integer, got -1"),
    ],
)
def test_bad_input_is_one_line_and_writes_nothing(tmp_path, capsys, monkeypatch, args, message):
    monkeypatch.chdir(tmp_path)
    assert cli.main(["reproduce", *args]) == 2
    err = capsys.readouterr().err
    assert err.startswith("kitbench reproduce: error: ") and err.count("\n") == 1 and message in err
    assert list(tmp_path.iterdir()) == []


def _finished(policy_dir: Path, training) -> bytes:
    """A finished training of `training` in `policy_dir`, as `run.train` leaves one; its weights' bytes."""
    from kitbench.training import run

    finished = training.train_dir / "checkpoints" / "last" / "pretrained_model"
    finished.mkdir(parents=True)
    weights = b"the published seed's weights"
    (finished / "model.safetensors").write_bytes(weights)
    stamp = {"request": training.request(), "trained": {"seconds": 1.0, "steps": 7}}
    (policy_dir / run.TRAIN_STAMP).write_text(json.dumps(stamp))
    return weights


def _trained_here(monkeypatch, after: Reading | None = None) -> list[list[str]]:
    """lerobot-train stood in for: each command it is asked to run, and a checkpoint where it would write one; the
    reference workload read after it reads `after` (1.0 s, alone on its threads, when not given)."""
    from kitbench.training import run

    commands: list[list[str]] = []

    def fake_train(command, log, env=None, follow=None):
        commands.append(command)
        out = Path(next(a for a in command if a.startswith("--output_dir=")).split("=", 1)[1])
        model = out / "checkpoints" / "last" / "pretrained_model"
        model.mkdir(parents=True)
        (model / "model.safetensors").write_bytes(b"new weights")
        (model / "train_config.json").write_text(json.dumps({"steps": 3, "seed": 2000}))
        log.write_text("num_total_params=5\n")
        return 2.0

    monkeypatch.setattr(run, "run_logged", fake_train)
    monkeypatch.setattr(run, "read", lambda threads: after or Reading(1.0, 1.0))
    return commands


def test_a_different_request_never_replaces_a_finished_training(tmp_path, monkeypatch):
    from kitbench.training import run

    policy_dir, data = tmp_path / "seed1000", tmp_path / "data"
    config = ROOT / "policies" / f"{CONFIG}.json"
    published = run.Training(config, data, policy_dir, "2", seed=1000, data_stamp="d")
    weights = _finished(policy_dir, published)
    commands = _trained_here(monkeypatch)
    assert run.train(published)["reused"] is True

    for other, change, remedy in (
        (
            run.Training(config, data, policy_dir, "1", seed=2000, data_stamp="d"),
            "OMP_NUM_THREADS 2 -> 1; arguments --seed=1000 -> --seed=2000",
            "pass --overwrite to replace it, or another --out to keep it",
        ),
        # the cost of seed 1000's checkpoint: an unset OMP_NUM_THREADS chose another thread count
        (
            run.Training(config, data, policy_dir, "1", seed=1000, data_stamp="d"),
            "OMP_NUM_THREADS 2 -> 1",
            "run with OMP_NUM_THREADS=2 to reuse it, or pass --overwrite",
        ),
        (run.Training(config, data, policy_dir, "2", seed=1000, data_stamp="e"), "the data it trained on", "--out"),
    ):
        with pytest.raises(run.FinishedTraining) as refused:
            run.train(other)
        message = str(refused.value)
        assert "\n" not in message and message.startswith(f"{policy_dir / 'train'} holds a finished training")
        assert f"of another request ({change}); " in message and remedy in message, message
    assert commands == []  # nothing was trained, and nothing lost
    assert (published.train_dir / "checkpoints" / "last" / "pretrained_model" / "model.safetensors").read_bytes() == (
        weights
    )
    assert json.loads((policy_dir / run.TRAIN_STAMP).read_text())["request"] == published.request()


def test_overwrite_replaces_a_finished_training_and_its_reports_are_made_again(tmp_path, monkeypatch, capsys):
    from kitbench.training import run

    policy_dir, data = tmp_path / "seed1000", tmp_path / "data"
    config = ROOT / "policies" / f"{CONFIG}.json"
    _finished(policy_dir, run.Training(config, data, policy_dir, "2", seed=1000, data_stamp="d"))
    out = tmp_path / "eval_lift_peg_upright"
    out.mkdir()
    (out / run.REPORT_JSON).write_text(json.dumps({"success": "the old checkpoint's"}))
    command = ["kitbench", "eval", "--policy", f"lerobot:{policy_dir / 'train'}"]
    out.with_name(out.name + ".request.json").write_text(json.dumps(command))
    commands = _trained_here(monkeypatch)

    other = run.Training(config, data, policy_dir, "2", seed=2000, data_stamp="d")
    trained = run.train(other, overwrite=True)
    assert trained["reused"] is False and len(commands) == 1 and "--seed=2000" in commands[0]
    model = other.train_dir / "checkpoints" / "last" / "pretrained_model" / "model.safetensors"
    assert model.read_bytes() == b"new weights"
    assert json.loads((policy_dir / run.TRAIN_STAMP).read_text())["request"] == other.request()
    said = capsys.readouterr().err.strip().splitlines()
    assert said == [f"replacing {other.train_dir} (--overwrite; it differs: arguments --seed=1000 -> --seed=2000)"]

    # the same command scores another checkpoint now: the report made before it finished is not reused
    os.utime(out / run.REPORT_JSON, (1, 1))

    def fake_eval(command, log, env=None, follow=None):
        (out / run.REPORT_JSON).write_text(json.dumps({"success": "the new checkpoint's"}))
        return 1.0

    monkeypatch.setattr(run, "run_logged", fake_eval)
    assert run.evaluate(command, out, trained["stamp"]) == ({"success": "the new checkpoint's"}, False)
    assert run.evaluate(command, out, trained["stamp"]) == ({"success": "the new checkpoint's"}, True)


def test_reproduce_refuses_to_train_over_a_finished_training_before_it_records(tmp_path, monkeypatch, capsys):
    from kitbench.recording import recorder
    from kitbench.training import run

    out = tmp_path / "run"
    policy_dir = out / f"seed{SEED}"
    config = ROOT / "policies" / f"{CONFIG}.json"
    weights = _finished(policy_dir, run.Training(config, out / "data", policy_dir, "1", seed=SEED, data_stamp="d"))

    def no_recording(*args, **kwargs):
        raise AssertionError("recorded before the refusal")

    monkeypatch.setattr(recorder, "record", no_recording)
    assert cli.main(["reproduce", CONFIG, "--steps", "2", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("kitbench reproduce: error: ")
    assert "holds a finished training of another request (" in err and "--steps=2" in err
    assert "pass --overwrite to replace it, or another --out to keep it" in err
    model = policy_dir / "train" / "checkpoints" / "last" / "pretrained_model" / "model.safetensors"
    assert model.read_bytes() == weights and sorted(p.name for p in out.iterdir()) == [f"seed{SEED}"]


def test_an_unpublished_config_trains_on_the_threads_its_kind_was_measured_fastest_on(monkeypatch):
    from kitbench.training import run

    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    monkeypatch.setattr(run.os, "cpu_count", lambda: 2)
    policies = ROOT / "policies"
    # cameras: two torch threads beside the one loader worker; the state: one thread beside two workers
    assert run.train_threads(policies / "act_lift_peg_upright_rgb_96_cpu.json") == "2"
    assert run.train_threads(policies / "act_lift_peg_upright_state.json") == "1"
    monkeypatch.setattr(run.os, "cpu_count", lambda: 16)  # a GPU's config leaves the cores to its 8 loader workers
    assert run.train_threads(policies / "act_lift_peg_upright_rgb.json") == "8"
    assert run.train_threads(policies / "act_lift_peg_upright_state.json", published_threads=3) == "3"
    monkeypatch.setenv("OMP_NUM_THREADS", "4")
    assert run.train_threads(policies / "act_lift_peg_upright_rgb_96_cpu.json", published_threads=2) == "4"


GPU_CONFIG = "act_lift_peg_upright_rgb"


def test_a_gpu_config_is_refused_without_cuda_in_one_line_naming_cpu_and_writes_nothing(tmp_path, capsys, monkeypatch):
    from kitbench.training import device

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(device, "cuda_available", lambda: False)
    assert cli.main(["reproduce", GPU_CONFIG, "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("kitbench reproduce: error: ") and err.count("\n") == 1
    assert f"{GPU_CONFIG}.json trains on cuda and torch sees no CUDA device here" in err and "--cpu" in err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("bf16", [True, False])
def test_cpu_trains_a_gpu_config_as_the_cpu_configs_train_and_is_part_of_its_request(tmp_path, monkeypatch, bf16):
    from kitbench.reproduce import ReproduceConfig, plan
    from kitbench.training import device, precision

    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    monkeypatch.delenv(precision.VAR, raising=False)
    monkeypatch.setattr(device, "cuda_available", lambda: False)
    monkeypatch.setattr(precision, "cpu_bf16", lambda: bf16)
    planned = plan(ReproduceConfig(GPU_CONFIG, out=tmp_path / "run", seed=56977, cpu=True))
    command = planned.training.request()["command"]
    amp = "--policy.use_amp=true" if bf16 else "--policy.use_amp=false"
    assert {"--policy.device=cpu", "--num_workers=1", amp} <= set(command), command
    assert "--seed=56977" in command and f"--config_path={ROOT / 'policies' / GPU_CONFIG}.json" in command
    # every core to torch, as a CPU camera config trains, not the cores a GPU's 8 loader workers leave
    assert planned.training.threads == str(os.cpu_count())
    # a CPU config trains as it is with --cpu or without
    for cpu in (True, False):
        flags = plan(ReproduceConfig("act_lift_peg_upright_rgb_96_cpu", out=tmp_path / f"cpu{cpu}", cpu=cpu))
        assert "--policy.device=cpu" not in flags.training.request()["command"]
    monkeypatch.setattr(device, "cuda_available", lambda: True)  # where torch sees CUDA, the GPU config as written
    on_gpu = plan(ReproduceConfig(GPU_CONFIG, out=tmp_path / "gpu")).training
    gpu = on_gpu.request()["command"]
    assert not any(a.startswith(("--policy.device", "--num_workers", "--policy.use_amp")) for a in gpu), gpu
    # the threads its figure's CPU trainings ran on (`cpu = true`) are not a GPU training's: the loader workers' cores
    assert load_published()[GPU_CONFIG].cpu and on_gpu.threads == str(max(1, (os.cpu_count() or 1) - 8))


def test_save_every_keeps_checkpoints_along_the_training_and_is_part_of_its_request(tmp_path):
    from kitbench.reproduce import ReproduceConfig, plan

    planned = plan(ReproduceConfig(CONFIG, out=tmp_path / "run", steps=20, save_every=5))
    command = planned.training.request()["command"]
    assert "--save_freq=5" in command and "--steps=20" in command
    assert (
        "--save_freq=5"
        not in plan(ReproduceConfig(CONFIG, out=tmp_path / "run", steps=20)).training.request()["command"]
    )


def test_each_training_seed_keeps_its_reports_and_verdict_beside_its_checkpoint(tmp_path):
    """Seeds reproduced into one folder share the recording; one seed's scoring never replaces another's."""
    from kitbench.reproduce import ReproduceConfig, plan

    first = plan(ReproduceConfig(CONFIG, out=tmp_path / "run", seed=21418))
    second = plan(ReproduceConfig(CONFIG, out=tmp_path / "run", seed=76247))
    assert first.training.data == second.training.data == tmp_path / "run" / "data"
    for planned in (first, second):
        assert planned.report_dir("lift_peg_upright").parent == planned.result.parent == planned.policy_dir
    assert first.report_dir("lift_peg_upright") != second.report_dir("lift_peg_upright")
