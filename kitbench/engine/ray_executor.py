"""The Ray executor: `workers` Ray actors, each building its env and policy once and running many episodes.

Start-up is paid per actor, not per episode (an actor builds the env and loads a policy in seconds). Faults are
Ray's to handle: an actor whose process dies (`kill -9`, a lost node) is restarted by Ray, which re-runs the
jobs it had not returned (`max_restarts`, `max_task_retries`); the driver receives each job's result once, in
seed order, so every episode is committed or scored exactly once. Results carry their bytes (episode frames,
MCAP logs, videos) back through Ray's object store: nothing is written on the worker's disk for the driver.

Addresses: `auto` joins the cluster this machine runs (`ray start`, RAY_ADDRESS), else starts a local one;
`local` always starts a local one; `host:port` joins that head. A cluster on a loopback address, and every local
instance started here, stays on loopback: Ray would otherwise advertise the machine's network address.
"""

from __future__ import annotations

import importlib.util
import os
import socket
from pathlib import Path
from typing import Any

from kitbench.engine.executor import ClusterLost, Executor
from kitbench.engine.work import Work, single_threaded_torch
from kitbench.errors import KitbenchError

# An actor (or its node) may die this many times before the run fails; each death re-runs the jobs it held.
# A job that kills its worker every time (a simulator crash on one seed) fails the run after as many retries.
MAX_RESTARTS = 3
CONNECT_TIMEOUT_S = 5.0
# The file `ray start` writes with the address of the cluster this machine runs (Ray reads it for "auto").
RAY_CURRENT_CLUSTER = "ray_current_cluster"
_LOOPBACK = ("127.", "localhost", "::1")


def _ray_temp_dir() -> Path:
    return Path(os.environ.get("RAY_TMPDIR", "/tmp")) / "ray"


def _parse(address: str) -> tuple[str, int]:
    host, sep, port = address.rpartition(":")
    if not sep or not host or not port.isdigit():
        raise KitbenchError(
            f"ray_address {address!r} is not host:port; valid choices: auto, local, or a Ray head's host:port"
        )
    return host.strip("[]"), int(port)


def _answers(host: str, port: int) -> bool:
    try:
        with socket.create_connection((host, port), timeout=CONNECT_TIMEOUT_S):
            return True
    except OSError:
        return False


def running_cluster() -> str | None:
    """The address of the Ray cluster this machine runs (RAY_ADDRESS, else the one `ray start` left), if it
    answers; None if there is none (a crashed cluster's stale address counts as none)."""
    address = os.environ.get("RAY_ADDRESS") or None
    if address is None:
        current = _ray_temp_dir() / RAY_CURRENT_CLUSTER
        address = current.read_text().strip() if current.is_file() else None
    if not address or address in ("auto", "local"):
        return None
    try:
        host, port = _parse(address)
    except KitbenchError:
        return None
    return address if _answers(host, port) else None


def check_ray(address: str) -> None:
    """Refuse, in one line and before anything runs, a Ray executor that cannot start: Ray missing, an address
    that is not host:port, or a head that does not answer."""
    if importlib.util.find_spec("ray") is None:
        raise KitbenchError(
            "--executor ray needs Ray: pip install 'kitbench[ray]' (or use --executor local; valid: local, ray)"
        )
    if address in ("auto", "local"):
        return
    host, port = _parse(address)
    if not _answers(host, port):
        raise KitbenchError(
            f"no Ray cluster answers at ray_address {address!r} (tried for {CONNECT_TIMEOUT_S:.0f} s); start one "
            "with `ray start --head`, or use auto or local"
        )


def _connect(address: str, workers: int) -> bool:
    """Connect this process to Ray (see the module docstring); returns whether this call did (and so must
    disconnect)."""
    target = None if address == "local" else (running_cluster() if address == "auto" else address)
    if target is None or target.startswith(_LOOPBACK):
        # Ray turns a loopback address into the machine's network address (for multi-node clusters) unless told
        # this is a one-machine cluster; read when Ray is imported, so set first.
        os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    import ray

    if ray.is_initialized():  # the caller's own Ray session (a notebook, a driver script): use it, leave it
        return False
    options: dict[str, Any] = {"logging_level": "ERROR", "log_to_driver": False}
    if target is None:  # "local" said explicitly: otherwise Ray joins the cluster RAY_ADDRESS or `ray start` names
        ray.init(address="local", num_cpus=workers, include_dashboard=False, **options)
    else:
        ray.init(address=target, **options)
    return True


class _EpisodeWorker:
    """The Ray actor: one `Work`, set up once; shows as `ray::_EpisodeWorker` in process lists."""

    def __init__(self, work: Work):
        single_threaded_torch()
        work.setup()
        single_threaded_torch()
        self._work = work

    def run(self, job: Any) -> Any:
        return self._work.run(job)

    def pid(self) -> int:
        return os.getpid()


class RayExecutor(Executor):
    """`workers` actors of one CPU each; a job goes to the actor with the fewest jobs outstanding."""

    def __init__(self, workers: int, address: str = "auto"):
        self.workers = workers
        self.address = address
        self._actors: list[Any] = []
        self._outstanding: list[list[Any]] = []
        self._connected = False
        self._cluster: str | None = None  # the head's address, once connected
        self._lost = False

    def start(self, work: Work) -> None:
        check_ray(self.address)
        self._connected = _connect(self.address, self.workers)
        import ray

        self._cluster = ray.get_runtime_context().gcs_address
        cpus = ray.cluster_resources().get("CPU", 0)
        if cpus < self.workers:
            self.close()
            raise KitbenchError(
                f"workers {self.workers} needs {self.workers} CPUs but the Ray cluster has {cpus:g}; "
                f"use --workers {max(int(cpus), 1)} or add nodes"
            )
        actor = ray.remote(num_cpus=1, max_restarts=MAX_RESTARTS, max_task_retries=MAX_RESTARTS)(_EpisodeWorker)
        self._actors = [actor.remote(work) for _ in range(self.workers)]
        self._outstanding = [[] for _ in self._actors]
        try:
            ray.get([a.pid.remote() for a in self._actors])  # set-up errors surface here, before the first job
        except BaseException:
            self.close()  # no actors or Ray session left behind by a run that never started
            raise

    def submit(self, job: Any) -> Any:
        import ray

        for refs in self._outstanding:
            if refs:
                _, refs[:] = ray.wait(refs, num_returns=len(refs), timeout=0)
        index = min(range(len(self._actors)), key=lambda i: len(self._outstanding[i]))
        ref = self._actors[index].run.remote(job)
        self._outstanding[index].append(ref)
        return ref

    def _head_lost(self) -> bool:
        if self._cluster is None:
            return False
        try:
            host, port = _parse(self._cluster)
        except KitbenchError:
            return False
        return not _answers(host, port)

    def result(self, handle: Any) -> Any:
        import ray
        from ray.exceptions import RayError, RayTaskError

        try:
            return ray.get(handle)
        except RayTaskError as exc:
            raise exc.as_instanceof_cause() from None  # the job's own exception, as a local run raises it
        except RayError as exc:
            # an actor that died with its node is Ray's to restart; with the head gone there is nothing left to run on
            if self._head_lost():
                self._lost = True
                raise ClusterLost(f"the Ray cluster at {self._cluster} was lost: its head no longer answers") from None
            raise RuntimeError(
                f"a Ray worker died more than {MAX_RESTARTS} times running this job; giving up ({exc})"
            ) from exc

    def close(self) -> None:
        import ray

        for actor in [] if self._lost else self._actors:  # a lost cluster has no actors left to stop
            ray.kill(actor, no_restart=True)
        self._actors, self._outstanding = [], []
        if self._connected:
            ray.shutdown()
            self._connected = False
