"""`RolloutEngine`: a seed-ordered queue of jobs, a window of them in flight on an executor, results in order.

The consumer (the dataset writer, the scorer) sees results in the order of its jobs whatever the executor and the
number of workers, so a dataset or a report depends only on its settings. The window is two jobs per worker: one
running and one queued keeps every worker busy while the consumer waits on the oldest job, and bounds how much
finished work waits in memory (rgb episodes are megabytes each).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable, Iterator
from typing import Any

from kitbench.engine.executor import Executor
from kitbench.engine.work import Work

JOBS_IN_FLIGHT_PER_WORKER = 2


class RolloutEngine:
    """Runs `Work` on an executor; use as a context manager (the executor's workers are started on entry and
    stopped on exit, also when the consumer stops early)."""

    def __init__(self, executor: Executor, work: Work):
        self.executor = executor
        self.work = work
        self._started = False

    @property
    def workers(self) -> int:
        return self.executor.workers

    def __enter__(self) -> RolloutEngine:
        self.executor.start(self.work)
        self._started = True
        return self

    def __exit__(self, *exc) -> None:
        if self._started:
            self._started = False
            self.executor.close()

    def results(self, jobs: Iterable[Any], needed: Callable[[], int] | None = None) -> Iterator[tuple[Any, Any]]:
        """(job, result) for each job, in the jobs' order. `jobs` is read lazily, so it may be endless (a recording
        that keeps only successes reads seeds until it has enough); the consumer stops by leaving the loop, and
        jobs still in flight then are abandoned. `needed()`, asked before each submission, bounds the jobs in
        flight: a recording that still needs k episodes runs at most k, so it ends with no episode computed in
        vain and no worker stopped in the middle of one."""
        if not self._started:
            raise RuntimeError("RolloutEngine.results() outside its `with` block")
        window = JOBS_IN_FLIGHT_PER_WORKER * self.executor.workers
        source = iter(jobs)
        pending: deque[tuple[Any, Any]] = deque()
        exhausted = False
        while True:
            while not exhausted and len(pending) < (window if needed is None else min(window, needed())):
                job = next(source, _END)
                if job is _END:
                    exhausted = True
                else:
                    pending.append((job, self.executor.submit(job)))
            if not pending:
                return
            job, handle = pending.popleft()
            yield job, self.executor.result(handle)

    def map(self, jobs: Iterable[Any]) -> Iterator[Any]:
        """The results alone, in order."""
        return (result for _, result in self.results(jobs))


_END = object()
