"""Executors on this machine: the job runs in this process (one worker), or in a pool of spawned processes."""

from __future__ import annotations

import multiprocessing as mp
import signal
from typing import Any

from kitbench.engine.executor import Executor
from kitbench.engine.work import Work, single_threaded_torch


class InProcessExecutor(Executor):
    """One worker, this process: the same code path as a pool, without processes (and so debuggable)."""

    workers = 1

    def __init__(self) -> None:
        self._work: Work | None = None

    def start(self, work: Work) -> None:
        work.setup()
        self._work = work

    def submit(self, job: Any) -> Any:
        return job  # run when its result is asked for: a job's failure then comes after the results before it

    def result(self, handle: Any) -> Any:
        assert self._work is not None, "start() first"
        return self._work.run(handle)

    def close(self) -> None:
        if self._work is not None:
            self._work.close()
            self._work = None


# -- the pool: one Work per spawned process ----------------------------------------------------------
_WORK: list[Work] = []


def _pool_init(work: Work) -> None:
    # Ctrl-C and a terminal hang-up reach the whole process group: the driver handles them (it commits or writes
    # what it has, then ends the pool). SIGTERM keeps its default: it is how the pool ends its workers.
    for signum in (signal.SIGINT, signal.SIGHUP):
        signal.signal(signum, signal.SIG_IGN)
    single_threaded_torch()
    work.setup()
    single_threaded_torch()  # setup may have imported torch (a lerobot policy)
    _WORK.append(work)


def _pool_run(job: Any) -> Any:
    return _WORK[0].run(job)


class PoolExecutor(Executor):
    """`workers` spawned processes (spawn, not fork: SAPIEN and torch hold threads and GPU/Vulkan handles that
    a fork would copy half-made)."""

    def __init__(self, workers: int):
        self.workers = workers
        self._pool: Any = None

    def start(self, work: Work) -> None:
        self._pool = mp.get_context("spawn").Pool(self.workers, initializer=_pool_init, initargs=(work,))

    def submit(self, job: Any) -> Any:
        return self._pool.apply_async(_pool_run, (job,))

    def result(self, handle: Any) -> Any:
        return handle.get()

    def close(self) -> None:
        if self._pool is not None:
            self._pool.terminate()
            self._pool.join()
            self._pool = None
