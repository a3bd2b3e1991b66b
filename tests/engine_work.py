"""Small `Work` classes for the rollout-engine tests (importable by spawned processes and Ray actors)."""

from __future__ import annotations

import os
import time
from pathlib import Path

from kitbench.engine import Work


class SleepWork(Work):
    """Job n sleeps (n % 3) * 20 ms, so later jobs often finish first, and returns (n, the worker's pid)."""

    def setup(self) -> None:
        self.ready = True

    def run(self, job):
        time.sleep((job % 3) * 0.02)
        return job * job, os.getpid()


class DiesOnceWork(Work):
    """Job `victim` kills its worker process the first time it runs (a marker file remembers across processes);
    every job writes one line per run to `runs`, so a test sees how often each job ran."""

    def __init__(self, folder: str, victim: int):
        self.folder = folder
        self.victim = victim

    def setup(self) -> None:
        pass

    def run(self, job):
        folder = Path(self.folder)
        with open(folder / "runs", "a") as f:
            f.write(f"{job}\n")
        marker = folder / "died"
        if job == self.victim and not marker.exists():
            marker.write_text(str(os.getpid()))
            os._exit(9)  # as a kill -9 would: no cleanup, no exception
        return job * 10


class FailingWork(Work):
    """Job 3 raises: the error reaches the consumer as the job's own exception."""

    def setup(self) -> None:
        pass

    def run(self, job):
        if job == 3:
            raise ValueError(f"job {job} failed")
        return job
