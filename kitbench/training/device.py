"""Where a config trains: its own `policy.device`, or this machine's CPU for a config made for a GPU.

The GPU configs (`policy.device = "cuda"`, 8 loader workers, fp32) train as they are only where torch sees CUDA.
On a machine without it `kitbench reproduce` refuses them in one line unless asked to train on the CPU, where
lerobot-train gets the CPU configs' settings: the CPU device, one loader worker (a sample costs a loader a
millisecond where an update costs a second: docs/training.md) and bf16 autocast where the CPU computes bf16
(`kitbench.training.precision`). The model, data, batch and steps stay the config's: the same training in another
precision, whose figure counts for the config and whose minutes are this machine's.
"""

from __future__ import annotations

import json
from pathlib import Path

from kitbench.errors import KitbenchError
from kitbench.training.precision import OFF_FLAG, keep_cpu_amp

ON_FLAG = "--policy.use_amp=true"


def config_device(config: Path) -> str:
    """The device `config` trains on as written (lerobot's default, cuda, where it names none)."""
    return (json.loads(Path(config).read_text()).get("policy") or {}).get("device") or "cuda"


def cuda_available() -> bool:
    import torch

    return torch.cuda.is_available()


def cpu_flags(config: Path, cpu: bool) -> tuple[str, ...]:
    """lerobot-train's flags that train `config` on this CPU when `cpu` asks for it and the config names another
    device; none otherwise. Refuses, in one line, a GPU config where torch sees no CUDA and `cpu` is not asked."""
    device = config_device(config)
    if device == "cpu":
        return ()
    if not cpu:
        if device == "cuda" and not cuda_available():
            raise KitbenchError(
                f"{Path(config).name} trains on cuda and torch sees no CUDA device here; valid choices: a machine "
                "with one, or --cpu to train it on this CPU (its model, data, batch and steps; bf16 autocast where "
                "the CPU computes bf16, one loader worker)"
            )
        return ()
    return ("--policy.device=cpu", "--num_workers=1", ON_FLAG if keep_cpu_amp() else OFF_FLAG)
