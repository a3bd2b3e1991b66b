"""Progress of long runs (record, eval): a tqdm bar on a terminal, plain lines every few seconds otherwise.

tqdm redraws its bar with carriage returns, which a log file or a CI console keeps as one frame per redraw; a
recording piped to a file grew by thousands of such frames. Off a terminal, one line every `PLAIN_INTERVAL`
seconds (and a last one at the end) says the same.
"""

from __future__ import annotations

import sys
import time
from typing import Protocol, TextIO

PLAIN_INTERVAL = 10.0  # s between plain progress lines


class Progress(Protocol):
    def update(self, n: int = 1) -> None: ...

    def set_postfix(self, **values: object) -> None: ...

    def close(self) -> None: ...


def _duration(seconds: float) -> str:
    return f"{seconds:.0f} s" if seconds < 120 else f"{seconds / 60:.0f} min"


class PlainProgress:
    """`desc: n/total (pct) [elapsed, rate, time left] key=value ...` lines, at most one per `interval` seconds."""

    def __init__(
        self, total: int, desc: str, unit: str = "ep", stream: TextIO | None = None, interval: float = PLAIN_INTERVAL
    ):
        self.total, self.desc, self.unit, self.interval = total, desc, unit, interval
        self.stream = stream if stream is not None else sys.stderr
        self.n = 0
        self.postfix: dict[str, object] = {}
        self.start = self.last = time.monotonic()
        self.closed = False

    def _line(self) -> str:
        elapsed = time.monotonic() - self.start
        pct = f" ({self.n / self.total:.0%})" if self.total else ""
        rate = f", {self.n / elapsed:.2f} {self.unit}/s" if elapsed > 0 else ""
        if elapsed > 0 and 0 < self.n < self.total:
            rate += f", {_duration((self.total - self.n) * elapsed / self.n)} left"  # at the rate so far
        extra = "".join(f" {k}={v}" for k, v in self.postfix.items())
        return f"{self.desc}: {self.n}/{self.total}{pct} [{elapsed:.0f} s{rate}]{extra}"

    def update(self, n: int = 1) -> None:
        self.n += n
        now = time.monotonic()
        if now - self.last >= self.interval:
            self.last = now
            print(self._line(), file=self.stream, flush=True)

    def set_postfix(self, **values: object) -> None:
        self.postfix = values

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            print(self._line(), file=self.stream, flush=True)


def progress(
    total: int, desc: str, unit: str = "ep", stream: TextIO | None = None, interval: float = PLAIN_INTERVAL
) -> Progress:
    """A progress bar for `total` items: tqdm when `stream` (default stderr) is a terminal, plain lines (one per
    `interval` seconds at most) else."""
    stream = stream if stream is not None else sys.stderr
    if stream.isatty():
        from tqdm import tqdm

        return tqdm(total=total, desc=desc, unit=unit, dynamic_ncols=True, file=stream)
    return PlainProgress(total, desc, unit, stream, interval)
