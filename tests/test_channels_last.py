"""CPU convolutions in channels-last memory order in `lerobot-train`, through the kitbench plugin, and nowhere
else; the switch turns it off, and a bad value of it is one logged line naming the choices.

Each case starts a fresh interpreter that begins as lerobot's own scripts do (the training script's import, then
lerobot's plugin discovery), trains a small convolutional model two steps and reports its weight's memory order
and its gradients against the same steps with the plugin off: the order changes, the numbers do not.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from kitbench.training import channels_last

PROGRAM = """
import json, sys, torch
if sys.argv[1] == "train":
    import lerobot.scripts.lerobot_train  # what the lerobot-train console script imports before main()
from lerobot.utils.import_utils import register_third_party_plugins
register_third_party_plugins()
torch.manual_seed(0)
model = torch.nn.Sequential(torch.nn.Conv2d(3, 8, 3), torch.nn.ReLU(), torch.nn.Conv2d(8, 4, 3))
opt = torch.optim.AdamW(model.parameters(), 1e-3)
params = list(model.parameters())
for _ in range(2):
    loss = model(torch.rand(2, 3, 16, 16, generator=torch.Generator().manual_seed(1))).square().mean()
    loss.backward(); opt.step(); opt.zero_grad()
print(json.dumps({
    "channels_last": model[0].weight.is_contiguous(memory_format=torch.channels_last)
        and not model[0].weight.is_contiguous(),
    "same_parameters": all(a is b for a, b in zip(params, model.parameters())),
    "weights": [p.detach().flatten()[:16].tolist() for p in model.parameters()],
}))
"""


def run(script: str, value: str | None) -> tuple[dict, str]:
    env = {k: v for k, v in os.environ.items() if k != channels_last.VAR}
    env["OMP_NUM_THREADS"] = "1"
    if value is not None:
        env[channels_last.VAR] = value
    done = subprocess.run(
        [sys.executable, "-c", PROGRAM, script], capture_output=True, text=True, env=env, timeout=300, check=False
    )
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout.strip().splitlines()[-1]), done.stderr


@pytest.mark.parametrize(
    ("script", "value", "converted"),
    [("train", None, True), ("train", "1", True), ("train", "0", False), ("eval", None, False)],
)
def test_the_plugin_converts_cpu_convolutions_in_training_only(script, value, converted):
    result, _ = run(script, value)
    assert result["channels_last"] is converted
    assert result["same_parameters"]  # the optimizer's parameters are the model's, converted in place


def test_the_order_changes_the_layout_not_the_training():
    on, _ = run("train", None)
    off, _ = run("train", "0")
    for a, b in zip(on["weights"], off["weights"], strict=True):
        assert a == pytest.approx(b, rel=1e-5, abs=1e-6)


def test_a_bad_value_is_one_line_naming_it_and_the_choices_and_keeps_the_order():
    result, stderr = run("train", "fast")
    assert result["channels_last"] is False
    lines = [line for line in stderr.splitlines() if channels_last.VAR in line]
    assert len(lines) == 1
    assert "'fast'" in lines[0] and "1, true, yes, on, 0, false, no, off" in lines[0]
