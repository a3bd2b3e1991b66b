"""The convolutions of a policy trained on the CPU in channels-last (NHWC) memory order, while `lerobot-train` runs.

oneDNN's CPU convolutions are faster on NHWC tensors, and a torchvision backbone is NCHW unless converted: an
update of `act_lift_peg_upright_rgb` (128x128, batch 64, bf16 autocast) took 0.64 s instead of 0.66, of
`diffusion_lift_peg_upright_rgb` 0.96 instead of 1.06 (`bench/train_levers.py`, docs/training.md). lerobot-train
has no setting for it and builds the model inside its script, so the LeRobot plugin installs a torch forward
pre-hook (`torch.nn.modules.module.register_module_forward_pre_hook`, public API) that converts each 2-D
convolution's weight, on the CPU, to channels-last the first time it runs, and its input with it (the layers
after it follow the input's order). The parameters stay the same objects, so the optimizer's state follows.
`KITBENCH_CHANNELS_LAST=0` keeps torch's default; other programs that import the plugin are left as they are.
"""

from __future__ import annotations

import weakref

import torch

from kitbench.training.switch import in_training, wanted

VAR = "KITBENCH_CHANNELS_LAST"

_converted: weakref.WeakSet = weakref.WeakSet()
_handle = None


def _to_channels_last(module: torch.nn.Module, args: tuple) -> tuple | None:
    if not isinstance(module, torch.nn.Conv2d) or not args or not isinstance(args[0], torch.Tensor):
        return None
    x = args[0]
    if x.device.type != "cpu" or x.dim() != 4:
        return None
    if module not in _converted:
        for parameter in (module.weight, module.bias):
            if parameter is not None and parameter.dim() == 4:
                parameter.data = parameter.data.contiguous(memory_format=torch.channels_last)
        _converted.add(module)
    if x.is_contiguous(memory_format=torch.channels_last):
        return None
    return (x.contiguous(memory_format=torch.channels_last), *args[1:])


def install() -> bool:
    """Convert CPU convolutions to channels-last in this process when it runs lerobot's training script and the
    switch is on (it is unless `KITBENCH_CHANNELS_LAST` says off); True when installed."""
    global _handle
    if _handle is not None:
        return True
    if not in_training() or not wanted(VAR, "torch's memory order kept"):
        return False
    # torch types the hook as returning None, though it takes the returned inputs too (documented)
    _handle = torch.nn.modules.module.register_module_forward_pre_hook(_to_channels_last)  # type: ignore[arg-type]
    return True
