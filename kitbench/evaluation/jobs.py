"""An evaluation's jobs: the suite's seeds and conditions as the engine's jobs (a seed, a perturbed trial, a batch
of seeds, an episode to save), and the loop that scores them, journaling each job as it comes back."""

from __future__ import annotations

from kitbench.engine import RolloutEngine
from kitbench.evaluation.episode import EpisodeResult
from kitbench.evaluation.journal import EvalJournal
from kitbench.evaluation.suite import Suite
from kitbench.evaluation.work import Batch, Save, Trial
from kitbench.recording.stops import StopSignals


def suite_jobs(suite: Suite, batch_size: int = 1, saving: bool = False) -> list[int | Trial | Batch | Save]:
    """The nominal seeds, then every seed under each perturbation and level (`suite.conditions`): one job a seed,
    or with `batch_size` > 1 one `Batch` per `batch_size` consecutive seeds of a condition; `saving`: the nominal
    seeds as `Save` jobs, whose episodes come back with their frames."""
    if batch_size > 1:
        seeds = suite.seeds
        return [
            Batch(tuple(seeds[i : i + batch_size]), condition)
            for condition in suite.conditions
            for i in range(0, len(seeds), batch_size)
        ]
    jobs: list[int | Trial | Batch | Save] = [Save(s) for s in suite.seeds] if saving else list(suite.seeds)
    for condition in suite.conditions[1:]:
        assert condition is not None
        jobs += [Trial(seed, *condition) for seed in suite.seeds]
    return jobs


def job_condition(job: int | Trial | Batch | Save) -> tuple[str, float] | None:
    if isinstance(job, Trial):
        return (job.perturbation, job.level)
    return job.condition if isinstance(job, Batch) else None


def score(
    engine: RolloutEngine,
    suite: Suite,
    jobs: list[int | Trial | Batch | Save],
    journaled: list[list[EpisodeResult]],
    journal: EvalJournal,
    progress: bool,
) -> tuple[list[EpisodeResult], dict[tuple[str, float], list[EpisodeResult]], list]:
    """The nominal results, the results under each (perturbation, level), in seed order, and the episodes the `Save`
    jobs kept: the first jobs' from the journal (`journaled`), the others run, each journaled as it comes back."""
    bar = None
    if progress:
        from kitbench.progress import progress as progress_bar

        bar = progress_bar(sum(len(job_seeds(job)) for job in jobs), f"eval {suite.task}")
    results: list[EpisodeResult] = []
    perturbed: dict[tuple[str, float], list[EpisodeResult]] = {}
    episodes: list = []

    def take(job, scored: list[EpisodeResult]) -> None:
        condition = job_condition(job)
        (results if condition is None else perturbed.setdefault(condition, [])).extend(scored)
        if bar is not None:
            bar.update(len(scored))
            if condition is None:
                bar.set_postfix(success=f"{sum(r.success for r in results) / len(results):.0%}")
            else:
                bar.set_postfix(condition=f"{condition[0]}={condition[1]:g}")

    try:
        for job, scored in zip(jobs, journaled, strict=False):
            if isinstance(job, Save):
                episodes.append(journal.episodes.load(job.seed)[0])
            take(job, scored)
        left = jobs[len(journaled) :]
        # SIGTERM and SIGHUP end the run as Ctrl-C does, never in the middle of journaling a finished job
        with StopSignals() as stops:
            for index, (job, result) in enumerate(zip(left, engine.map(left), strict=True), len(journaled)):
                episode = None
                if isinstance(job, Save):
                    result, episode = result
                    episodes.append(episode)
                scored = result if isinstance(job, Batch) else [result]
                with stops.storing():
                    journal.add(index, scored, episode)
                take(job, scored)
    finally:
        if bar is not None:
            bar.close()
    return results, perturbed, episodes


def job_seeds(job: int | Trial | Batch | Save) -> tuple[int, ...]:
    if isinstance(job, Batch):
        return job.seeds
    return (job if isinstance(job, int) else job.seed,)


def first_jobs(seeds: int, batch_size: int) -> int:
    """How many jobs hold the first `seeds` seeds of a suite without perturbations (a batch: `batch_size` seeds)."""
    return -(-seeds // batch_size)
