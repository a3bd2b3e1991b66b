"""The rollout engine that `kitbench record` and `kitbench eval` share: episode jobs in seed order, run by an
executor (this process, a local process pool, or Ray actors on a cluster), results handed back in seed order to
one consumer (the dataset writer, the scorer).

- `work.py`: `Work`, what a worker builds once (env, policy) and the jobs it runs.
- `executor.py`: `Executor`, the hooks every executor implements.
- `config.py`: `ExecutorConfig` (which executor, how many workers, where) and `make_executor`.
- `local.py`: the in-process and process-pool executors.
- `ray_executor.py`: the Ray executor (actors that build their env once and run many episodes).
- `engine.py`: `RolloutEngine`, the seed-ordered window of jobs in flight.
"""

from __future__ import annotations

from kitbench.engine.config import (
    EXECUTORS as EXECUTORS,
    ExecutorConfig as ExecutorConfig,
    make_executor as make_executor,
)
from kitbench.engine.engine import RolloutEngine as RolloutEngine
from kitbench.engine.executor import Executor as Executor
from kitbench.engine.work import Work as Work
