"""The rollout engine on this machine: results in job order whatever the executor, endless job lists, the first
job error reported after the results before it, and executor settings checked before anything runs."""

from __future__ import annotations

import itertools
import os

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
    if workers == 1:
        assert {pid for _, (_, pid) in got} == {os.getpid()}  # in this process


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


def test_suites_and_recipes_choose_the_executor_and_flags_override_them(tmp_path):
    from kitbench.evaluation.config import eval_config
    from kitbench.recording.config import load_recipe

    suite = tmp_path / "suite.toml"
    suite.write_text(
        '[suite]\ntask = "LiftPegUpright-v1"\nseeds = { start = 5, count = 3 }\n'
        'executor = "ray"\nworkers = 4\nray_address = "127.0.0.1:6379"\n'
    )
    from_suite = eval_config({"suite_file": suite})
    assert from_suite.executor == ExecutorConfig("ray", 4, "127.0.0.1:6379")
    flags = eval_config({"suite_file": suite, "executor": "local", "workers": 2})
    assert (flags.executor.executor, flags.executor.workers) == ("local", 2)
    assert from_suite.suite == flags.suite  # where it runs is not part of what the suite measures
    recipe = tmp_path / "recipe.toml"
    recipe.write_text(
        '[record]\ntask = "LiftPegUpright-v1"\nepisodes = 2\nout = "x"\nexecutor = "ray"\nshard_episodes = 10\n'
    )
    config = load_recipe(recipe, workers=3)
    executor = config.executor
    assert (executor.executor, executor.workers, executor.shard_episodes, executor.ray_address) == (
        "ray",
        3,
        10,
        "auto",
    )
    identity = config.info().identity()
    assert "executor" not in identity and "shard_episodes" not in identity
