"""`Executor`: the hooks every executor implements (in this process, a local pool, Ray actors)."""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any

from kitbench.engine.work import Work
from kitbench.errors import KitbenchError


class ClusterLost(KitbenchError):
    """The cluster the workers ran on is gone (its head no longer answers): nothing more can run there."""


class Executor(ABC):
    """Runs jobs of one `Work` on `workers` workers. The engine calls `start`, then `submit`/`result` any number
    of times (results are asked for in submission order), then `close`."""

    workers: int

    @abstractmethod
    def start(self, work: Work) -> None:
        """Start the workers, each with its own copy of `work` set up."""

    @abstractmethod
    def submit(self, job: Any) -> Any:
        """Queue `job`; returns a handle for `result`."""

    @abstractmethod
    def result(self, handle: Any) -> Any:
        """Wait for a submitted job's result (a job's exception is raised here)."""

    @abstractmethod
    def close(self) -> None:
        """Stop the workers; jobs still queued are dropped."""
