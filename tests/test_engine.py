"""The rollout engine on this machine: results in job order whatever the executor, endless job lists, the first
job error reported after the results before it, and executor settings checked before anything runs."""

from __future__ import annotations

import itertools

import pytest

from kitbench.engine import ExecutorConfig, RolloutEngine, make_executor
from kitbench.engine.local import InProcessExecutor, PoolExecutor
from kitbench.errors import KitbenchError
from tests.engine_work import FailingWork, SleepWork


@pytest.mark.parametrize("workers", [1, 2])
def test_results_come_in_job_order(workers):
    executor = make_executor(ExecutorConfig("local", workers))
    assert isinstance(executor, InProcessExecutor if workers == 1 else PoolExecutor)
    with RolloutEngine(executor, SleepWork()) as engine:
        got = list(engine.results(range(12)))
    assert [job for job, _ in got] == list(range(12))
    assert [value for _, (value, _) in got] == [n * n for n in range(12)]
    pids = {pid for _, (_, pid) in got}
    assert len(pids) == workers  # two workers both ran jobs


def test_an_endless_job_list_is_read_lazily_and_left_early():
    with RolloutEngine(make_executor(ExecutorConfig("local", 2)), SleepWork()) as engine:
        taken = []
        for job, _ in engine.results(itertools.count(100)):
            taken.append(job)
            if len(taken) == 5:
                break
    assert taken == [100, 101, 102, 103, 104]


@pytest.mark.parametrize("workers", [1, 2])
def test_a_failed_job_raises_its_own_error_after_the_results_before_it(workers):
    seen = []
    with (
        RolloutEngine(make_executor(ExecutorConfig("local", workers)), FailingWork()) as engine,
        pytest.raises(ValueError, match="job 3 failed"),
    ):
        seen.extend(engine.map(range(6)))  # keeps what came before the error
    assert seen == [0, 1, 2]


def test_workers_are_capped_by_the_number_of_jobs():
    assert make_executor(ExecutorConfig("local", 4), jobs=1).workers == 1
    assert make_executor(ExecutorConfig("local", 4), jobs=3).workers == 3


@pytest.mark.parametrize(
    ("config", "message"),
    [
        (ExecutorConfig("spark"), "unknown executor 'spark'; valid choices: local, ray"),
        (ExecutorConfig("local", 0), "workers must be a positive integer, got 0"),
        (ExecutorConfig("local", ray_address="10.0.0.1:6379"), "ray_address '10.0.0.1:6379' needs executor ray"),
        (ExecutorConfig("ray", ray_address="head-node"), "ray_address 'head-node' is not host:port"),
    ],
)
def test_bad_executor_settings_are_one_line_errors(config, message):
    with pytest.raises(KitbenchError) as err:
        config.validate()
    assert str(err.value).startswith(message) and "\n" not in str(err.value)
