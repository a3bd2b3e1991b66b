"""What a worker does: `Work` is built once per worker (an env, a policy) and then runs many jobs.

A `Work` travels to its worker as its settings (pickled before `setup`: a spawned process or a Ray actor gets a
copy), so everything heavy is built in `setup`, on the worker. Results travel back the same way; they must hold
everything the consumer needs (no paths on the worker's disk: on a cluster the worker is another machine).
"""

from __future__ import annotations

import sys
from abc import ABC, abstractmethod
from typing import Any


class Work(ABC):
    """The jobs of one command (record: a seed → an episode; eval: a seed → a score, or a video)."""

    @abstractmethod
    def setup(self) -> None:
        """Build what the jobs share (env, policy). Runs once on each worker, before its first job."""

    @abstractmethod
    def run(self, job: Any) -> Any:
        """Run one job and return its result; deterministic in the job, whichever worker runs it."""

    def close(self) -> None:  # noqa: B027 - optional hook: most work has nothing to release
        """Release what `setup` built (the worker is about to go)."""


def single_threaded_torch() -> None:
    """One torch thread per worker: N workers on N cores would otherwise oversubscribe them (torch starts one
    thread per core in every process)."""
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(1)
