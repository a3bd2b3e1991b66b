"""What the throughput benchmarks share: comma-separated cell filters (`names`, `counts`), the Ray instance their
Ray cells run on (started once per run, on loopback, as the cluster a user's runs join with `--ray-address auto`;
its start-up is a one-time cost, printed on its own), the table's executor labels, and the timing of results as
they reach the consumer."""

from __future__ import annotations

import argparse
import os
import time
from contextlib import contextmanager

from kitbench.engine import RolloutEngine

_ARRIVALS: list[float] = []  # perf_counter() when each result of the running cell reached the consumer


class _TimedEngine(RolloutEngine):
    """The rollout engine, noting when each result reaches the consumer."""

    def results(self, jobs, needed=None):
        for item in super().results(jobs, needed):
            _ARRIVALS.append(time.perf_counter())
            yield item


@contextmanager
def timed_engine(module):
    """Swap `module.RolloutEngine` (the recorder's or the runner's) for one that notes arrival times; yields the
    list they go to."""
    _ARRIVALS.clear()
    saved = module.RolloutEngine
    module.RolloutEngine = _TimedEngine
    try:
        yield _ARRIVALS
    finally:
        module.RolloutEngine = saved


def executor_label(executor: str, workers: int) -> str:
    if executor == "local":
        return "local:in-proc" if workers == 1 else "local:pool"
    return executor


def start_ray(cpus: int) -> float:
    """Start a local Ray instance with `cpus` CPUs in this process (the executor then uses it as it is and leaves
    it running); returns the seconds it took."""
    # loopback only, as kitbench's own local instances (kitbench/engine/ray_executor.py); read when Ray is imported
    os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    import ray

    start = time.perf_counter()
    ray.init(address="local", num_cpus=cpus, include_dashboard=False, logging_level="ERROR", log_to_driver=False)
    return time.perf_counter() - start


def names(valid: tuple[str, ...]):
    def parse(text: str) -> list[str]:
        items = [s.strip() for s in text.split(",") if s.strip()]
        if not items or any(s not in valid for s in items):
            raise argparse.ArgumentTypeError(f"{text!r}: a comma-separated list of {', '.join(valid)}")
        return list(dict.fromkeys(items))

    return parse


def counts(text: str) -> list[int]:
    try:
        items = [int(s) for s in text.split(",") if s.strip()]
    except ValueError:
        items = []
    if not items or min(items) < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: a comma-separated list of worker counts >= 1")
    return list(dict.fromkeys(items))
