"""Temporal ensembling for a policy whose lerobot config has none (Diffusion): re-plan every step, and act on the
weighted mean of every chunk's prediction for this step.

ACT's `temporal_ensemble_coeff` is its own config's (lerobot runs it); Diffusion predicts from a window of its last
`n_obs_steps` observations and executes `n_action_steps` of each chunk open loop. With the same option kitbench
predicts a chunk of `n_action_steps` from the window at every step and weighs the predictions for a step as ACT
does, exp(-coeff * i) with i = 0 the oldest, so 0.01 averages nearly evenly and a large coefficient favours the
oldest plan.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Iterable
from typing import TYPE_CHECKING

from kitbench.errors import KitbenchError

if TYPE_CHECKING:
    import torch

ENSEMBLE_OPTION = "temporal_ensemble_coeff"


def check_coefficient(value: object) -> float:
    """The option's value as a float; anything but a finite number is one line."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise KitbenchError(
            f"policy option {ENSEMBLE_OPTION}={value!r}: must be a finite number (e.g. 0.01, ACT's; 0 weighs every "
            f"chunk alike, more favours older chunks)"
        )
    return float(value)


class ChunkEnsembler:
    """Each step's action: the weighted mean of what every chunk still covering this step predicted for it."""

    def __init__(self, coeff: object):
        self.coeff = check_coefficient(coeff)
        self.reset()

    def reset(self) -> None:
        self._chunks: list[tuple[torch.Tensor, int]] = []  # (chunk, steps since it was predicted), oldest first

    def step(self, chunk: torch.Tensor) -> torch.Tensor:
        """`chunk` (batch, steps, action), predicted from this step's observations: this step's action (batch,
        action)."""
        import torch

        self._chunks.append((chunk, 0))
        predictions = torch.stack([c[:, age] for c, age in self._chunks])  # (chunks, batch, action)
        weights = torch.exp(-self.coeff * torch.arange(len(self._chunks), dtype=predictions.dtype))
        action = (weights[:, None, None] * predictions).sum(0) / weights.sum()
        self._chunks = [(c, age + 1) for c, age in self._chunks if age + 1 < c.shape[1]]
        return action


class ObservationWindow:
    """The last `size` preprocessed observations, stacked as `(batch, size, ...)` the way Diffusion's own queues
    stack them; the first observation fills the window (as lerobot's `populate_queues` does)."""

    def __init__(self, size: int, keys: Iterable[str]):
        self.size = size
        self.keys = tuple(keys)
        self._frames: deque[dict] = deque(maxlen=size)

    def reset(self) -> None:
        self._frames.clear()

    def push(self, batch: dict) -> dict:
        import torch

        frame = {k: batch[k] for k in self.keys}
        if not self._frames:
            self._frames.extend([frame] * self.size)
        else:
            self._frames.append(frame)
        return {k: torch.stack([f[k] for f in self._frames], dim=1) for k in self.keys}


class EnsembledChunks:
    """What a policy acts on with kitbench's ensembling: every step a chunk predicted from the observation window,
    averaged with the earlier chunks' predictions for this step."""

    def __init__(self, coeff: object, window: int, keys: Iterable[str]):
        self.ensembler = ChunkEnsembler(coeff)
        self.window = ObservationWindow(window, keys)

    def reset(self) -> None:
        self.ensembler.reset()
        self.window.reset()

    def step(self, predict: Callable[[dict], torch.Tensor], batch: dict) -> torch.Tensor:
        """This step's action (batch, action) from the preprocessed `batch`; `predict` maps a window of
        observations to a chunk (batch, steps, action)."""
        return self.ensembler.step(predict(self.window.push(batch)))
