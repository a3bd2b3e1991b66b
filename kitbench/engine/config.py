"""The settings that choose an executor (`ExecutorConfig`: `--executor`, `--workers`, `--ray-address`, and the
same keys in recipes and suites), and `make_executor`."""

from __future__ import annotations

from dataclasses import dataclass

from kitbench.config.checks import one_of, positive_int
from kitbench.config.declare import setting, validate
from kitbench.engine.executor import Executor
from kitbench.errors import KitbenchError

EXECUTORS = ("local", "ray")
DEFAULT_RAY_ADDRESS = "auto"


def _address(name: str, value: object) -> None:
    if not isinstance(value, str) or not value:
        raise KitbenchError(f"{name} must be auto, local or host:port, got {value!r}")


@dataclass
class ExecutorConfig:
    """Where episodes run. `local`: in this process with 1 worker, else a pool of `workers` spawned processes.
    `ray`: `workers` Ray actors on the cluster at `ray_address` (`auto`: the running cluster this machine knows
    of, else a new local one; `local`: always a new local one; or the head's `host:port`)."""

    # Where episodes run: local (this process, or --workers processes) or ray (actors on a Ray cluster).
    executor: str = setting("local", check=one_of(EXECUTORS))
    # Simulator workers (processes or Ray actors); the results do not depend on them.
    workers: int = setting(1, check=positive_int)
    # With executor ray: auto (the running cluster, else a local one), local, or a head's host:port.
    ray_address: str = setting(DEFAULT_RAY_ADDRESS, check=_address)

    def validate(self) -> None:
        """Every check that can fail before anything is written: the names, Ray being installed, and an explicit
        `ray_address` answering."""
        validate(self)
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
