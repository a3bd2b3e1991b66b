"""Denormals flushed to zero in `lerobot-train` by the kitbench plugin, and nowhere else.

Each case starts a fresh interpreter that begins as lerobot's own scripts do (the training script's import, then
lerobot's plugin discovery) and multiplies denormal floats on two torch threads: flushed, every product is zero.
"""

from __future__ import annotations

import os
import subprocess
import sys
import types

import pytest

from kitbench.training import denormals

PROGRAM = """
import sys, torch
if sys.argv[1] == "train":
    import lerobot.scripts.lerobot_train  # what the lerobot-train console script imports before main()
from lerobot.utils.import_utils import register_third_party_plugins
register_third_party_plugins()
torch.set_num_threads(2)
x = torch.full((4_000_000,), 1e-39)  # denormal in float32
print("nonzero", int((x * 1.5).count_nonzero()))
"""
N = 4_000_000


def run(script: str, value: str | None) -> tuple[int, str]:
    env = {k: v for k, v in os.environ.items() if k != denormals.VAR}
    env["OMP_NUM_THREADS"] = "2"
    if value is not None:
        env[denormals.VAR] = value
    done = subprocess.run(
        [sys.executable, "-c", PROGRAM, script], capture_output=True, text=True, env=env, timeout=300, check=False
    )
    assert done.returncode == 0, done.stderr[-2000:]
    nonzero = int(done.stdout.split("nonzero")[-1])
    return nonzero, done.stderr


@pytest.mark.parametrize(
    ("script", "value", "flushed"),
    [("train", None, True), ("train", "0", False), ("eval", None, False)],
)
def test_the_plugin_flushes_denormals_in_training_only(script, value, flushed):
    nonzero, _ = run(script, value)
    assert nonzero == (0 if flushed else N)


def test_a_bad_value_is_one_line_naming_it_and_the_choices_and_keeps_denormals():
    nonzero, stderr = run("train", "maybe")
    assert nonzero == N
    lines = [line for line in stderr.splitlines() if denormals.VAR in line]
    assert len(lines) == 1
    assert "'maybe'" in lines[0] and "1, true, yes, on, 0, false, no, off" in lines[0]


def test_python_dash_m_counts_as_training(monkeypatch):
    monkeypatch.delitem(sys.modules, denormals.TRAINING_SCRIPT, raising=False)
    main = types.ModuleType("__main__")
    monkeypatch.setitem(sys.modules, "__main__", main)
    assert not denormals.in_training()
    main.__spec__ = types.SimpleNamespace(name=denormals.TRAINING_SCRIPT)  # type: ignore[assignment]
    assert denormals.in_training()


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--denormals", "flush,sometimes"], "'sometimes' is not one of flush, keep"),
        (["--resume", "policies"], "--resume policies: not a lerobot-train checkpoint"),
    ],
)
def test_train_throughput_names_a_bad_flag_in_one_line(flags, message):
    bench = os.path.join(os.path.dirname(__file__), "..", "bench", "train_throughput.py")
    done = subprocess.run([sys.executable, bench, *flags], capture_output=True, text=True, timeout=60, check=False)
    assert done.returncode == 2
    assert done.stdout == ""
    assert done.stderr.count("\n") == 1 and message in done.stderr
