"""Denormal floats flushed to zero while `lerobot-train` runs.

A weight that never gets a gradient from the data (its only gradient is weight decay's) shrinks towards zero, and
its Adam moments become denormal (below 1.2e-38 in float32), where x86 arithmetic takes a microcode path: after
~2,500 steps the optimizer step of `diffusion_assembling_kits_state` took four times as long on the CPU
(docs/training.md, "Denormals"). Flushing them to zero, as TensorFlow's CPU thread pools do, left every weight
that touches data bit for bit the same there. The LeRobot plugin calls `install` when lerobot imports it, which
`lerobot-train` does first thing, before torch starts the thread pool whose threads inherit the setting;
`KITBENCH_FLUSH_DENORMALS=0` keeps IEEE denormals.
"""

from __future__ import annotations

import torch

from kitbench.training.switch import OFF, ON, TRAINING_SCRIPT, in_training, wanted as switch_wanted

VAR = "KITBENCH_FLUSH_DENORMALS"
__all__ = ["OFF", "ON", "TRAINING_SCRIPT", "VAR", "in_training", "install", "wanted"]


def wanted() -> bool:
    """What `KITBENCH_FLUSH_DENORMALS` asks for (on when unset); a value outside ON and OFF is one logged line and
    leaves torch's default."""
    return switch_wanted(VAR, "denormals kept")


def install() -> bool:
    """Flush denormals to zero in this process when it runs lerobot's training script (the threads it starts from
    now on inherit it); True when done. Evaluation and recording keep torch's default, so their results stay
    bit-identical to runs without the plugin."""
    if not in_training() or not wanted():
        return False
    return bool(torch.set_flush_denormal(True))
