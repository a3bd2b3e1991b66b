"""`bench/learnability.py` over training seeds and seed sets: its argument checks are one line each with nothing
written, and a two-training-seed run at a tiny step count scores every checkpoint on both suites, prints the pooled
table, and picks up where it stopped when run again."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

from kitbench.training.reference import Reading
from tests import launch
from tests.lerobot_cli import OFFLINE

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "bench" / "learnability.py"
TASK = "LiftPegUpright-v1"


def _bench(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    command = [sys.executable, str(BENCH), "--task", TASK, "--demos", "2", *args]
    return launch.run(command, capture_output=True, text=True, env=OFFLINE, cwd=cwd, timeout=1500, check=False)


@pytest.mark.parametrize(
    "args,message",
    [
        (["--train-seeds", "1000,-3"], "--train-seeds '1000,-3': '-3' is not a non-negative integer"),
        (["--train-seeds", "x"], "--train-seeds 'x': 'x' is not a non-negative integer"),
        (["--suites", "standard,nightly"], "unknown suite 'nightly'; valid choices: standard, heldout or a suite file"),
        (["--recipe", "datasets/none.toml"], "no recipe datasets/none.toml"),
    ],
)
def test_bad_arguments_are_one_line_and_write_nothing(tmp_path, args, message):
    run = _bench(*args, "--out", str(tmp_path / "out"), cwd=ROOT)
    assert run.returncode == 2 and run.stdout == ""
    assert run.stderr.count("\n") == 1 and message in run.stderr, run.stderr
    assert not (tmp_path / "out").exists()


def test_a_tag_given_to_another_recipe_is_refused_before_it_records_over_that_run(tmp_path):
    run_dir = tmp_path / "out" / "lift_peg_upright_state_d2"
    run_dir.mkdir(parents=True)
    stamp = run_dir / "record_request.json"
    stamp.write_text(json.dumps({"command": ["kitbench", "record", "datasets/lift_peg_upright_so101_state.toml"]}))
    run = _bench("--recipe", "datasets/lift_peg_upright_state.toml", "--out", str(tmp_path / "out"), cwd=ROOT)
    assert run.returncode == 2 and run.stderr.count("\n") == 1, run.stderr
    assert "holds a recording of datasets/lift_peg_upright_so101_state.toml" in run.stderr
    assert "give this recipe another --tag" in run.stderr
    assert [p.name for p in run_dir.iterdir()] == ["record_request.json"]  # nothing recorded or removed


def test_a_sweep_takes_the_settings_a_checkpoint_takes_kitbench_ensembling_on_diffusion_included():
    from bench.learnability import UsageError, parse_sweep

    sweep = parse_sweep(["temporal_ensemble_coeff=0.01,0.1", "n_action_steps=8"], "diffusion")
    assert sweep == (
        (("temporal_ensemble_coeff", 0.01), ("n_action_steps", 8)),
        (("temporal_ensemble_coeff", 0.1), ("n_action_steps", 8)),
    )
    with pytest.raises(UsageError, match="the diffusion policy has no setting 'chunk_size'"):
        parse_sweep(["chunk_size=5"], "diffusion")


def _tiny_config(where: Path) -> Path:
    """The shipped ACT LiftPegUpright config cut to a few parameters and no in-training evaluation."""
    config = json.loads((ROOT / "policies" / "act_lift_peg_upright_state.json").read_text())
    config.pop("env", None)
    config["policy"].update(dim_model=32, dim_feedforward=64, n_heads=2, device="cpu")
    config.update(batch_size=4, num_workers=0, save_freq=2, log_freq=1)
    path = where / "act_lift_peg_upright_state.json"
    path.write_text(json.dumps(config))
    return path


def _forked(command: list[str], log: Path, env: dict[str, str] | None = None, follow=None) -> float:
    """`run.run_logged` with the command a fork of the test's server (`tests.launch`) instead of a fresh
    interpreter: its output in `log` after the `$ command` line, handed to `follow`, its seconds or CommandFailed.
    (`kitbench reproduce`'s test runs its commands through `run_logged` itself.)"""
    from kitbench.training import run

    log.parent.mkdir(parents=True, exist_ok=True)
    start = time.monotonic()
    done = launch.run(command, env={**run.ENV, **(env or {})}, timeout=1500)
    output = done.stdout + done.stderr
    log.write_bytes(f"$ {run.shell_line(command, env)}\n".encode() + output)
    if follow is not None:
        follow(output)
    if done.returncode != 0:
        raise run.CommandFailed(command, log, done.returncode)
    return time.monotonic() - start


def _bench_here(monkeypatch, capsys, *args: str) -> tuple[int, str]:
    """`bench/learnability.py` run in this process, its recording, trainings and evaluations each a process of its
    own (`_forked`), its reference workload cut to a few updates: what it times is not the point here. Its exit
    status and what it printed."""
    import bench.learnability as learnability
    from kitbench.training import reference, run

    monkeypatch.setattr(run, "run_logged", _forked)
    monkeypatch.setattr(reference, "WARMUP", 1)
    monkeypatch.setattr(reference, "STEPS", 2)
    monkeypatch.chdir(ROOT)
    monkeypatch.setattr(sys, "argv", ["learnability.py", "--task", TASK, "--demos", "2", *args])
    code = learnability.main()
    captured = capsys.readouterr()
    return code, captured.out + captured.err


@pytest.mark.parametrize(
    "config,obs,camera",
    [("act_lift_peg_upright_rgb_96_cpu", "rgb", True), ("act_lift_peg_upright_state", "state", False)],
)
def test_the_cost_of_a_camera_config_says_the_reference_workload_does_not_carry_it(
    tmp_path, capsys, config, obs, camera
):
    import bench.learnability as learnability

    argv = [
        "--task",
        TASK,
        "--obs",
        obs,
        "--config",
        str(ROOT / "policies" / f"{config}.json"),
        "--out",
        str(tmp_path / "out"),
    ]
    plan = learnability.check_args(learnability.build_parser().parse_args([*argv, "--demos", "2"]))
    learnability.print_cost(plan, Reading(5.0, 1.0))
    printed = capsys.readouterr().out
    assert "cost: about " in printed and "min a training" in printed and "busy" not in printed
    assert ("does not carry a camera config's minutes between machines" in printed) is camera
    learnability.print_cost(plan, Reading(5.0, 0.5))  # another process held the cores as it was timed
    busy = capsys.readouterr().out
    assert "cost: the machine was busy as the run began: the reference workload had 50% of its " in busy
    assert not (tmp_path / "out").exists()


def test_the_cost_of_a_gpu_config_whose_figure_trained_on_a_cpu_is_not_scaled(tmp_path, capsys, monkeypatch):
    """`act_lift_peg_upright_rgb` publishes minutes and threads of 2-core trainings run with `kitbench reproduce
    --cpu`; this bench trains the config as written, so neither is carried over."""
    import os

    import bench.learnability as learnability

    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    config = ROOT / "policies" / "act_lift_peg_upright_rgb.json"
    argv = ["--task", TASK, "--obs", "rgb", "--config", str(config), "--out", str(tmp_path / "out"), "--demos", "2"]
    plan = learnability.check_args(learnability.build_parser().parse_args(argv))
    assert plan.train_threads == str(max(1, (os.cpu_count() or 1) - 8))  # not the CPU trainings' 2
    learnability.print_cost(plan, Reading(5.0, 1.0))
    printed = capsys.readouterr().out
    assert "cost: the published minutes are 2 CPU cores' with `kitbench reproduce --cpu`; not scaled here" in printed
    assert "cost: about " not in printed and not (tmp_path / "out").exists()


def test_two_training_seeds_on_two_suites_give_the_pooled_table_and_resume(tmp_path, needs_vulkan, monkeypatch, capsys):
    config = _tiny_config(tmp_path)
    args = ["--config", str(config), "--steps", "2", "--train-seeds", "1,2", "--suites", "standard,heldout"]
    args += ["--suite-episodes", "1", "--out", str(tmp_path / "out")]
    code, printed = _bench_here(monkeypatch, capsys, *args)
    assert code == 0, printed[-6000:]
    assert "plan: 1 recording(s) (2 demos), 2 training(s) (seeds 1, 2), 4 evaluation(s) on standard, heldout" in (
        printed
    )
    rows = [json.loads(line) for line in (tmp_path / "out" / "results.jsonl").read_text().splitlines()]
    assert sorted((r["train_seed"], r["suite_name"]) for r in rows) == [
        (1, "heldout"),
        (1, "standard"),
        (2, "heldout"),
        (2, "standard"),
    ]
    assert all(r["reference_seconds"] > 0 and r["success"]["episodes"] == 1 for r in rows)
    assert all(r["reference_seconds_after_training"] > 0 for r in rows)  # timed again as each training ended
    assert all(0 < r["reference_share"] and 0 < r["reference_share_after_training"] for r in rows)
    assert all(r["step_seconds"] > 0 for r in rows)  # lerobot-train's own step time, from each training's log
    assert printed.count("s at this run's start)") == 2  # one line per training
    heldout = [r for r in rows if r["suite_name"] == "heldout"]
    assert all("lift_peg_upright_heldout.toml" in r["commands"]["eval"] for r in heldout)
    pooled = printed[printed.index("act, 2 demos, training seeds 1, 2, suites standard, heldout:") :]
    k = sum(r["success"]["count"] for r in rows)
    assert f"  pooled: {k}/4 " in pooled and "  standard: " in pooled and "  heldout: " in pooled
    assert "gap standard − heldout: " in pooled and "per training seed: 1: " in pooled

    # run again: every checkpoint and report is reused, nothing is trained or scored twice
    code, printed = _bench_here(monkeypatch, capsys, *args)
    assert code == 0, printed[-6000:]
    assert printed.count("reused the checkpoint trained by the same command") == 2
    assert printed.count("s as it ended") == 2  # the stamp keeps what the training's end measured
    rows = [json.loads(line) for line in (tmp_path / "out" / "results.jsonl").read_text().splitlines()]
    assert len(rows) == 8 and all(r["train_reused"] for r in rows[4:])


def test_a_finished_training_is_refused_before_anything_is_recorded_unless_overwrite(tmp_path, monkeypatch, capsys):
    import bench.learnability as learnability
    from kitbench.training import run

    run_dir = tmp_path / "out" / "lift_peg_upright_state_d2"
    finished = run_dir / "act" / "train" / "checkpoints" / "last" / "pretrained_model"
    finished.mkdir(parents=True)
    (finished / "model.safetensors").write_bytes(b"weights")
    (run_dir / "act" / run.TRAIN_STAMP).write_text(json.dumps({"request": {"command": ["lerobot-train"]}}))
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))

    def nothing_runs(command, log, env=None, follow=None):
        raise AssertionError(f"ran {command}")

    monkeypatch.setattr(run, "run_logged", nothing_runs)
    argv = ["learnability.py", "--task", TASK, "--demos", "2", "--out", str(tmp_path / "out")]
    monkeypatch.setattr(sys, "argv", argv)
    assert learnability.main() == 2
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err.count("\n") == 1, captured.err
    assert captured.err.startswith(f"learnability: error: {run_dir / 'act' / 'train'} holds a finished training")
    assert "pass --overwrite to replace it, or another --out to keep it" in captured.err
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before

    # --overwrite goes on to record (here: the stand-in refuses to run anything)
    monkeypatch.setattr(sys, "argv", [*argv, "--overwrite"])
    monkeypatch.setattr(learnability, "read", lambda threads: Reading(1.0, 1.0))
    with pytest.raises(AssertionError, match=r"kitbench', 'record'"):
        learnability.main()
