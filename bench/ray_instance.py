"""The Ray instance the throughput benchmarks run their Ray cells on: started once per run, on loopback, as the
cluster a user's runs join (`--ray-address auto`); its start-up is a one-time cost, printed on its own."""

from __future__ import annotations

import os
import time


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
