"""A machine's speed at training the shipped state configs: a fixed workload, timed.

Training minutes measured on one machine mean little on another. The workload is what a state config's update is
made of, at its sizes: a 2-layer transformer encoder of width 256 (4 heads, feed-forward 1024) and a 1-layer decoder
on a batch of 32, forward, backward and an AdamW step, `STEPS` times on `threads` torch threads, from a fixed seed.
Its seconds (`reference_seconds`) travel with every published training time, so a time measured elsewhere reads as
`minutes x here / there` (`scaled_minutes`).

Another process on the same cores makes the reading meaningless, not just slower: torch's threads wait for each other
at every operation, and one of them descheduled stalls the rest (docs/training.md, "A busy machine"). `read` says
so: this process's CPU time over its threads' wall time while timed (`share`), about 1 alone, falls where another
process takes the cores from its threads.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

STEPS = 60
WARMUP = 5
# Below this share of its threads' time the process did not have the cores to itself.
BUSY_SHARE = 0.75


@dataclass(frozen=True)
class Reading:
    seconds: float
    share: float  # CPU seconds over threads x wall seconds while timed: ~1 alone

    @property
    def busy(self) -> bool:
        """Whether another process held the cores while the workload was timed (the seconds then read long)."""
        return self.share < BUSY_SHARE

    def busy_note(self, threads: int) -> str:
        """Why a busy reading says little, in the words every runner uses."""
        return (
            f"the reference workload had {self.share:.0%} of its {threads} thread(s)' time (about 100% alone: another "
            f"process held the cores), so its {self.seconds:.1f} s say little of this machine and minutes scaled by "
            "it read long"
        )


def reference_seconds(threads: int = 1) -> float:
    """Seconds for the fixed workload on `threads` torch threads (the threads are restored after)."""
    return read(threads).seconds


def read(threads: int = 1) -> Reading:
    """The fixed workload timed on `threads` torch threads, with the share of those threads' time it had."""
    import torch

    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        generator = torch.Generator().manual_seed(0)
        model = torch.nn.Transformer(
            d_model=256,
            nhead=4,
            num_encoder_layers=2,
            num_decoder_layers=1,
            dim_feedforward=1024,
            dropout=0.1,
            batch_first=True,
        )
        optimizer = torch.optim.AdamW(model.parameters(), lr=3e-4)
        source = torch.randn(32, 3, 256, generator=generator)
        target = torch.randn(32, 10, 256, generator=generator)

        def update() -> None:
            loss = (model(source, target) - target).abs().mean()
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()

        for _ in range(WARMUP):
            update()
        started, cpu = time.perf_counter(), time.process_time()
        for _ in range(STEPS):
            update()
        seconds = time.perf_counter() - started
        return Reading(seconds, (time.process_time() - cpu) / (seconds * threads))
    finally:
        torch.set_num_threads(previous)


def scaled_minutes(minutes: float, measured_on: float, here: float) -> float:
    """Minutes measured on a machine whose reference took `measured_on` s, as this one (`here` s) would take them."""
    return minutes * here / measured_on
