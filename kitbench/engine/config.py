"""The settings that choose an executor (`ExecutorConfig`: `--executor`, `--workers`, `--ray-address`, and the
same keys in recipes and suites), and `make_executor`."""

from __future__ import annotations

from dataclasses import dataclass

from kitbench.engine.executor import Executor
from kitbench.errors import KitbenchError, check_choice

EXECUTORS = ("local", "ray")
DEFAULT_RAY_ADDRESS = "auto"


def _is_count(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 1


@dataclass(frozen=True)
class ExecutorConfig:
    """Where episodes run. `local`: in this process with 1 worker, else a pool of `workers` spawned processes.
    `ray`: `workers` Ray actors on the cluster at `ray_address` (`auto`: the running cluster this machine knows
    of, else a new local one; `local`: always a new local one; or the head's `host:port`)."""

    executor: str = "local"
    workers: int = 1
    ray_address: str = DEFAULT_RAY_ADDRESS

    def validate(self) -> None:
        """Every check that can fail before anything is written: the names, Ray being installed, and an explicit
        `ray_address` answering."""
        check_choice("executor", self.executor, EXECUTORS)
        if not _is_count(self.workers):
            raise KitbenchError(f"workers must be a positive integer, got {self.workers!r}")
        if not isinstance(self.ray_address, str) or not self.ray_address:
            raise KitbenchError(f"ray_address must be auto, local or host:port, got {self.ray_address!r}")
        if self.executor == "ray":
            from kitbench.engine.ray_executor import check_ray

            check_ray(self.ray_address)
        elif self.ray_address != DEFAULT_RAY_ADDRESS:
            raise KitbenchError(
                f"ray_address {self.ray_address!r} needs executor ray, not {self.executor!r} (valid: local, ray)"
            )


def make_executor(config: ExecutorConfig, jobs: int | None = None) -> Executor:
    """The executor `config` describes, with no more workers than `jobs` when that is known."""
    workers = config.workers if jobs is None else max(1, min(config.workers, jobs))
    if config.executor == "ray":
        from kitbench.engine.ray_executor import RayExecutor

        return RayExecutor(workers, config.ray_address)
    from kitbench.engine.local import InProcessExecutor, PoolExecutor

    return InProcessExecutor() if workers == 1 else PoolExecutor(workers)
