"""Every report says what produced it (`report["provenance"]`): the checkpoint's digests, training step and dataset,
the execution settings the policy ran with, the software; `kitbench compare` prints what differs between two
reports where that can change an outcome, and a resume refuses weights that changed since the run began."""

from __future__ import annotations

import json
import os
import shutil
import signal
import sys
from pathlib import Path

import pytest

from kitbench import faults
from kitbench.cli import main
from kitbench.evaluation.compare import compare_reports
from kitbench.evaluation.config import EvalConfig
from kitbench.evaluation.provenance import checkpoint_files, vulkan
from kitbench.evaluation.runner import run_eval
from kitbench.evaluation.suite import adhoc_suite
from kitbench.metadata import RecordingInfo
from kitbench.policies.lerobot_policy import LeRobotPolicy
from kitbench.recording.recorder import RecordConfig, record
from tests import launch
from tests.lerobot_cli import lerobot_train, small_config

ROOT = Path(__file__).resolve().parents[1]
TASK = "LiftPegUpright-v1"
STEPS = 2
CHUNK = 5  # small_config's ACT: chunk_size 5, n_action_steps 5


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> tuple[Path, Path]:
    """(a small ACT checkpoint trained for STEPS steps, the kitbench dataset it was trained on)."""
    base = tmp_path_factory.mktemp("provenance")
    data = base / "data"
    record(RecordConfig.of(TASK, 2, data, mcap=False), progress=False)
    info = json.loads((data / "meta/info.json").read_text())["features"]
    inputs = [n for n in info if n.startswith("observation.")]
    lerobot_train(small_config(data, base, inputs, "act", steps=STEPS), data, base / "train", base)
    return base / "train", data


def _evaluate(checkpoint: Path, out: Path, **settings) -> dict:
    suite = adhoc_suite(TASK, 2)
    return run_eval(EvalConfig.of(suite, f"lerobot:{checkpoint}", out, device="cpu", **settings), progress=False)


@pytest.fixture(scope="module")
def reports(trained, tmp_path_factory) -> dict[str, Path]:
    """Reports of the checkpoint as saved and with `n_action_steps=2`."""
    base = tmp_path_factory.mktemp("reports")
    _evaluate(trained[0], base / "default")
    _evaluate(trained[0], base / "option", policy_options=(("n_action_steps", 2),))
    return {"default": base / "default", "option": base / "option"}


def _provenance(folder: Path) -> dict:
    return json.loads((folder / "report.json").read_text())["provenance"]


def test_the_report_names_the_weights_their_training_step_and_dataset(trained, reports):
    checkpoint, data = trained
    found = _provenance(reports["default"])["policy"]["checkpoint"]
    folder = checkpoint / "checkpoints" / "last" / "pretrained_model"
    assert found["path"] == str(folder.resolve())
    assert found["files"] == checkpoint_files(folder) and "model.safetensors" in found["files"]
    assert found["training_step"] == STEPS
    assert found["dataset"] == {
        "repo_id": "kitbench/test",
        "root": str(data),
        "episodes": 2,
        "episodes_sha256": RecordingInfo.read(data).episodes_sha256,
    }
    md = (reports["default"] / "report.md").read_text()
    assert "## Provenance" in md and f"sha256 `{found['sha256'][:16]}`, training step {STEPS}" in md


def _change_one_weight(folder: Path) -> None:
    from safetensors.torch import load_file, save_file

    weights = load_file(folder / "model.safetensors")
    name = sorted(weights)[0]
    weights[name].view(-1)[0] += 1e-3
    save_file(weights, folder / "model.safetensors", metadata={"format": "pt"})


def test_one_changed_weight_gives_another_digest(trained, tmp_path):
    original = trained[0] / "checkpoints" / "last" / "pretrained_model"
    changed = tmp_path / "pretrained_model"
    shutil.copytree(original, changed)
    _change_one_weight(changed)
    before, after = checkpoint_files(original), checkpoint_files(changed)
    assert [n for n in before if before[n] != after[n]] == ["model.safetensors"]


def test_execution_settings_are_those_the_policy_ran_with(trained, reports):
    ran = {
        name: LeRobotPolicy(str(trained[0]), options=options).config
        for name, options in (("default", {}), ("option", {"n_action_steps": 2}))
    }
    for name, config in ran.items():
        execution = _provenance(reports[name])["execution"]
        assert execution["policy_type"] == "act" and execution["batch_size"] == 1
        assert execution["chunk_size"] == config.chunk_size == CHUNK
        assert execution["n_action_steps"] == config.n_action_steps
        assert execution["n_obs_steps"] == config.n_obs_steps
        assert execution["temporal_ensemble_coeff"] is None
        assert (execution["device"], execution["dtype"]) == ("cpu", "float32")
    assert _provenance(reports["default"])["execution"]["n_action_steps"] == CHUNK  # the checkpoint's own
    assert _provenance(reports["option"])["execution"]["n_action_steps"] == 2  # the option given
    assert _provenance(reports["option"])["execution"]["policy_options"] == {"n_action_steps": 2}


def test_the_report_names_the_software_machine_and_suite(reports):
    import sapien
    import torch

    found = _provenance(reports["default"])
    assert found["software"]["torch"] == torch.__version__.split("+")[0]
    assert found["software"]["sapien"] == sapien.__version__
    assert found["software"]["python"] == ".".join(map(str, sys.version_info[:3]))
    assert found["machine"]["cores"] == os.cpu_count() and found["machine"]["cpu"]
    assert found["vulkan"] is None  # scored from the state: no render device was made, and none is named
    assert len(found["suite"]["digest"]) == 64 and found["suite"]["env"]["obs_mode"] == "state"
    assert found["suite"]["env"]["sim"]["sim_freq"] == 100


def test_compare_prints_what_differs_in_execution_and_versions_before_its_verdict(reports, tmp_path, capsys):
    other = tmp_path / "other"
    shutil.copytree(reports["option"], other)
    report = json.loads((other / "report.json").read_text())
    report["provenance"]["software"]["torch"] = "0.0.1"
    (other / "report.json").write_text(json.dumps(report))
    assert main(["compare", str(reports["default"]), str(other)]) == 0
    lines = capsys.readouterr().out.splitlines()
    torch_line = next(i for i, line in enumerate(lines) if "version torch:" in line)
    steps_line = next(i for i, line in enumerate(lines) if "execution n_action_steps: A 5, B 2" in line)
    assert max(torch_line, steps_line) < len(lines) - 1 and lines[-1].startswith("verdict:")
    assert lines[torch_line].strip().endswith("B '0.0.1'")
    comparison = compare_reports(reports["default"], reports["default"])
    assert comparison.provenance_differences == []


def test_a_resume_with_changed_weights_is_refused_in_one_line(trained, tmp_path):
    checkpoint = tmp_path / "ckpt"
    shutil.copytree(trained[0] / "checkpoints" / "last" / "pretrained_model", checkpoint)
    args = [sys.executable, "-m", "kitbench.cli", "eval", "--task", TASK, "--episodes", "3"]
    args += ["--policy", f"lerobot:{checkpoint}", "--device", "cpu", "--out", str(tmp_path / "report")]
    env = {**os.environ, "HF_HUB_OFFLINE": "1", faults.VAR: "eval.journaled:1"}
    env.pop(faults.OWNER_VAR, None)
    killed = launch.run(args, env=env, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert killed.returncode == -signal.SIGKILL, killed.stderr[-3000:]
    _change_one_weight(checkpoint)
    before = {p: p.read_bytes() for p in (tmp_path / "report").rglob("*") if p.is_file()}
    env.pop(faults.VAR)
    run = launch.run([*args, "--resume"], env=env, cwd=ROOT, capture_output=True, text=True, timeout=600)
    lines = run.stderr.strip().splitlines()
    assert run.returncode == 2 and len(lines) == 1, run.stderr[-3000:]
    assert "cannot resume" in lines[0] and "checkpoint file model.safetensors: journal sha256" in lines[0]
    assert {p: p.read_bytes() for p in (tmp_path / "report").rglob("*") if p.is_file()} == before


def test_the_vulkan_driver_is_named_without_a_device_of_its_own(needs_vulkan):
    from kitbench.doctor import check_vulkan

    found = vulkan()
    assert check_vulkan().detail.startswith(found["device"]) and isinstance(found["drivers"], dict)
