"""The report folder before a run: what it may hold (a new folder, a report to overwrite, an interrupted run to
resume), what a resumed run must share with the run it continues, and what an interrupted run's journal holds."""

from __future__ import annotations

from pathlib import Path

from kitbench.errors import KitbenchError
from kitbench.evaluation.compare_inputs import seeds_text
from kitbench.evaluation.config import EvalConfig
from kitbench.evaluation.episode import EpisodeResult
from kitbench.evaluation.jobs import job_condition, job_seeds, suite_jobs
from kitbench.evaluation.journal import EvalJournal
from kitbench.evaluation.output import REPORT_JSON
from kitbench.evaluation.provenance import outcome_differences, plain
from kitbench.evaluation.save_dataset import saving
from kitbench.evaluation.suite import Suite


def check_out_folder(out: Path, overwrite: bool, resume: bool = False) -> None:
    """Refuse a report folder that is not a folder, that holds something already (unless `overwrite`), that holds
    an interrupted evaluation (unless `resume` or `overwrite`), or a finished one to `resume`."""
    if out.exists() and not out.is_dir():
        raise KitbenchError(
            f"report folder {out} is a file; --out must be a folder (new, empty, or a report with --overwrite)"
        )
    if resume and overwrite:
        raise KitbenchError("--resume and --overwrite exclude each other: continue the evaluation, or start it again")
    journal = EvalJournal(out)
    if journal.exists():
        if not (resume or overwrite):
            raise KitbenchError(
                f"report folder {out} holds an interrupted evaluation ({journal.count()} episodes scored); continue "
                "it with --resume, or pass --overwrite to start again"
            )
        return
    if resume and (out / REPORT_JSON).is_file():
        raise KitbenchError(
            f"report folder {out} holds a finished evaluation: nothing to resume (pass --overwrite to run it again)"
        )
    if out.is_dir() and not overwrite and any(out.iterdir()):
        raise KitbenchError(f"report folder {out} exists; pass --overwrite to replace it")


def journaled_results(config: EvalConfig) -> list[EpisodeResult]:
    """The nominal episodes the journal in `config.out` holds whole, in seed order (none without a journal):
    what an interrupted run has scored, read without running anything."""
    journal = EvalJournal(config.out)
    if journal.settings() is None:
        return []
    jobs = suite_jobs(config.suite, config.policy.batch_size, saving=saving(config))
    done = journal.read([job_seeds(job) for job in jobs])
    return [r for job, scored in zip(jobs, done, strict=False) if job_condition(job) is None for r in scored]


def resume_settings(config: EvalConfig, suite: Suite, found: dict) -> dict:
    """What decides a run's scores, which a resumed run must share with the run it continues (the executor and
    its workers do not decide them, nor do the videos)."""
    checkpoint = found["policy"]["checkpoint"]
    return plain(
        {
            "policy": config.policy.policy,
            "checkpoint": None if checkpoint is None else checkpoint["files"],
            "suite": {k: v for k, v in suite.to_dict().items() if k not in ("name", "description", "source")},
            "execution": found["execution"],
            "software": found["software"],
            "save_dataset": None if config.output.save_dataset is None else str(Path(config.output.save_dataset)),
        }
    )


def resume_differences(journaled: dict, now: dict) -> list[str]:
    """How the command differs from the journal's run, one phrase each, naming both values."""
    found = [
        f"{key.replace('_', '-')}: journal {journaled.get(key)!r}, now {now[key]!r}"
        for key in ("policy", "save_dataset")
        if journaled.get(key) != now[key]
    ]
    old, new = journaled.get("checkpoint") or {}, now["checkpoint"] or {}
    for name in dict.fromkeys([*old, *new]):
        if old.get(name) != new.get(name) and journaled.get("policy") == now["policy"]:
            short = [None if d is None else d[:12] for d in (old.get(name), new.get(name))]
            found.append(f"checkpoint file {name}: journal sha256 {short[0]}, now {short[1]}")
    old_suite, new_suite = journaled.get("suite") or {}, now["suite"]
    for key in dict.fromkeys([*old_suite, *new_suite]):
        a, b = old_suite.get(key), new_suite.get(key)
        if a != b:
            shown = (seeds_text(a or []), seeds_text(b or [])) if key == "seeds" else (repr(a), repr(b))
            found.append(f"suite {key}: journal {shown[0]}, now {shown[1]}")
    found += outcome_differences(
        {k: journaled.get(k) for k in ("execution", "software")},
        {k: now[k] for k in ("execution", "software")},
        ("journal", "now"),
    )
    return found
