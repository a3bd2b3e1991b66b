"""bf16 autocast where the CPU computes in bf16, fp32 where it does not.

The CPU camera configs train under bf16 autocast (`policy.use_amp`, which lerobot-train turns into accelerate's
`mixed_precision="bf16"` on the CPU): 1.4-1.9x an update on a CPU with AVX-512 BF16 (docs/training.md). Where
oneDNN has no bf16 kernels (an AVX2-only CPU) the same autocast is ~20x slower than fp32 (docs/training.md, "A CPU
without bf16"), so every lerobot-train command kitbench builds turns it off there (`--policy.use_amp=false`): a
request of its own, whose checkpoint is another training's. `KITBENCH_CPU_AMP` decides instead of the CPU: `1` keeps
the config's autocast, `0` turns it off on any CPU.
"""

from __future__ import annotations

import json
import os
import platform
from pathlib import Path

from kitbench.errors import KitbenchError

VAR = "KITBENCH_CPU_AMP"
CHOICES = ("1", "0")
OFF_FLAG = "--policy.use_amp=false"
X86 = ("x86_64", "amd64", "i386", "i686", "x86")


def cpu_bf16() -> bool | None:
    """Whether torch's oneDNN computes bf16 on this CPU. On x86 it does with AVX-512 (natively with AVX-512 BF16 or
    AMX, emulated otherwise: torch's CPU capability "AVX512") and not with AVX2 alone; None on other CPUs, where the
    config's setting stands."""
    import torch

    if platform.machine().lower() not in X86:
        return None
    return torch.backends.cpu.get_cpu_capability() == "AVX512"


def keep_cpu_amp() -> bool:
    """`KITBENCH_CPU_AMP` if set (one line naming the choices otherwise), else unless the CPU computes no bf16."""
    value = os.environ.get(VAR, "").strip()
    if not value:
        return cpu_bf16() is not False
    if value not in CHOICES:
        raise KitbenchError(f"{VAR}={value!r}; valid choices: 1 (keep the config's bf16 autocast), 0 (train in fp32)")
    return value == "1"


def amp_flags(config: Path) -> tuple[str, ...]:
    """lerobot-train's flags for `config`'s precision here: the autocast off for a CPU config that asks for it on a
    CPU that does not compute bf16 (or as `KITBENCH_CPU_AMP` says); none otherwise."""
    policy = json.loads(Path(config).read_text()).get("policy") or {}
    if policy.get("device") == "cpu" and policy.get("use_amp") and not keep_cpu_amp():
        return (OFF_FLAG,)
    return ()


def why(flags: tuple[str, ...]) -> str | None:
    """The line a runner says when `flags` turned the autocast off; None when they did not."""
    if OFF_FLAG not in flags:
        return None
    cause = f"{VAR}=0" if os.environ.get(VAR, "").strip() == "0" else "this CPU computes no bf16 (oneDNN)"
    return f"training in fp32 ({OFF_FLAG}): {cause}, where bf16 autocast is ~20x slower than fp32; {VAR}=1 keeps it"
