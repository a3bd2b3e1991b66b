"""bf16 autocast where the CPU computes bf16, fp32 where it does not: every lerobot-train command kitbench builds
for a CPU camera config turns the autocast off on a CPU without bf16, says why, and KITBENCH_CPU_AMP decides
instead when set."""

from __future__ import annotations

from pathlib import Path

import pytest

from kitbench.errors import KitbenchError
from kitbench.training import precision
from kitbench.training.run import Training, train_command

ROOT = Path(__file__).resolve().parents[1]
CAMERA_CPU = ROOT / "policies" / "act_lift_peg_upright_rgb_96_cpu.json"
STATE = ROOT / "policies" / "act_lift_peg_upright_state.json"
GPU = ROOT / "policies" / "act_lift_peg_upright_rgb.json"


@pytest.fixture
def no_bf16(monkeypatch):
    monkeypatch.delenv(precision.VAR, raising=False)
    monkeypatch.setattr(precision, "cpu_bf16", lambda: False)


@pytest.fixture
def bf16(monkeypatch):
    monkeypatch.delenv(precision.VAR, raising=False)
    monkeypatch.setattr(precision, "cpu_bf16", lambda: True)


def test_a_cpu_camera_config_trains_in_fp32_on_a_cpu_without_bf16(no_bf16, tmp_path):
    assert precision.amp_flags(CAMERA_CPU) == ("--policy.use_amp=false",)
    command = train_command(CAMERA_CPU, tmp_path / "data", tmp_path / "train", 10, 1000, ("--save_freq=5",))
    assert command[-2:] == ["--policy.use_amp=false", "--save_freq=5"]  # the caller's flags still have the last word
    # a request of its own: a checkpoint trained under bf16 is not this one's
    training = Training(CAMERA_CPU, tmp_path / "data", tmp_path / "policy", "2")
    assert "--policy.use_amp=false" in training.request()["command"]
    assert precision.why(tuple(command)) == (
        "training in fp32 (--policy.use_amp=false): this CPU computes no bf16 (oneDNN), where bf16 autocast is "
        "~20x slower than fp32; KITBENCH_CPU_AMP=1 keeps it"
    )
    # configs that ask for no autocast, or train on a GPU, are left as written
    assert precision.amp_flags(STATE) == () and precision.amp_flags(GPU) == ()


def test_a_cpu_that_computes_bf16_keeps_the_configs_autocast(bf16, tmp_path):
    assert precision.amp_flags(CAMERA_CPU) == ()
    command = train_command(CAMERA_CPU, tmp_path / "data", tmp_path / "train")
    assert not any("use_amp" in arg for arg in command) and precision.why(tuple(command)) is None


def test_kitbench_cpu_amp_decides_instead_of_the_cpu(monkeypatch):
    monkeypatch.setattr(precision, "cpu_bf16", lambda: False)
    monkeypatch.setenv(precision.VAR, "1")
    assert precision.amp_flags(CAMERA_CPU) == ()
    monkeypatch.setattr(precision, "cpu_bf16", lambda: True)
    monkeypatch.setenv(precision.VAR, "0")
    assert precision.amp_flags(CAMERA_CPU) == ("--policy.use_amp=false",)
    assert precision.why(("--policy.use_amp=false",)).startswith(
        "training in fp32 (--policy.use_amp=false): KITBENCH_CPU_AMP=0"
    )
    monkeypatch.setenv(precision.VAR, "bf16")
    with pytest.raises(
        KitbenchError, match=r"^KITBENCH_CPU_AMP='bf16'; valid choices: 1 \(keep .*\), 0 \(train in fp32\)$"
    ):
        precision.amp_flags(CAMERA_CPU)


def test_the_demo_prints_the_command_this_cpu_trains_with(no_bf16):
    from kitbench.demo import learning_loop
    from kitbench.training.reference import Reading

    loop = learning_loop(cuda=False, reading=Reading(1.0, 1.0))
    assert loop.train[-1] == "--policy.use_amp=false" and "in fp32, as this CPU computes no bf16" in loop.minutes
    assert any(line.endswith("--policy.use_amp=false") for line in loop.lines())


def test_doctor_says_which_precision_the_camera_configs_train_in(monkeypatch):
    from kitbench.doctor import check_bf16

    monkeypatch.setattr(precision, "cpu_bf16", lambda: False)
    check = check_bf16()
    assert check.ok and check.detail.startswith("no (") and "train in fp32 here (--policy.use_amp=false" in check.detail
    monkeypatch.setattr(precision, "cpu_bf16", lambda: True)
    assert check_bf16().detail.startswith("yes (")
    monkeypatch.setattr(precision, "cpu_bf16", lambda: None)
    assert check_bf16().detail.endswith("the CPU camera configs train as written")


@pytest.mark.parametrize(
    "machine,capability,expected",
    [
        ("x86_64", "AVX512", True),  # oneDNN's avx512_core: bf16 natively or emulated
        ("x86_64", "AVX2", False),  # the CPU measured at 16-20x slower under autocast
        ("AMD64", "DEFAULT", False),
        ("aarch64", "SVE256", None),  # not measured: the config's setting stands
    ],
)
def test_bf16_is_read_from_torchs_cpu_capability(monkeypatch, machine, capability, expected):
    import platform

    import torch

    monkeypatch.delenv(precision.VAR, raising=False)
    monkeypatch.setattr(platform, "machine", lambda: machine)
    monkeypatch.setattr(torch.backends.cpu, "get_cpu_capability", lambda: capability)
    assert precision.cpu_bf16() is expected
    assert precision.amp_flags(CAMERA_CPU) == (() if expected is not False else ("--policy.use_amp=false",))
