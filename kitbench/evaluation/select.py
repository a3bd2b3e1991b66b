"""`kitbench select`: score every checkpoint a `lerobot-train` run saved (or those chosen) on a validation suite,
and name the best.

Each checkpoint is an ordinary `kitbench eval` report in `<out>/<step>/` (resumable, with its provenance); then
`select.json` and `select.md` tabulate step, successes of episodes and the Wilson 95% interval, `select.png` plots
success against the training step, and the best is named: the highest rate (ties: the later step), with whether
its interval overlaps the last checkpoint's and the exact McNemar p of the two on their paired seeds.

Checkpoints are chosen on a validation suite's seeds only (`purpose = "validation"` in its file): a checkpoint
picked on the seeds its figure is then scored on has a figure biased upwards by the picking. A test suite is
refused in one line, and so is a validation suite sharing a seed with a shipped test suite of its task.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from kitbench import shipped
from kitbench.config import declare
from kitbench.config.declare import setting
from kitbench.errors import KitbenchError
from kitbench.evaluation.provenance import training_step
from kitbench.evaluation.series import (
    Cell,
    SeriesSettings,
    cell_config,
    check_folder,
    eval_flags,
    rate_row,
    rate_text,
    run_cells,
    slug,
    write_summary,
)
from kitbench.evaluation.suite import Suite, load_suite, shipped_suites

SUMMARY = "select"
CHECKPOINT_FILES = ("config.json", "model.safetensors")


@dataclass
class CheckpointChoice:
    # A lerobot-train output folder: each checkpoint it saved (checkpoints/<step>/pretrained_model) is scored.
    train_dir: Path | None = setting(None, positional=True, metavar="train_dir")
    # Only these training steps of train_dir, comma-separated (default: every saved one), e.g. 20000,100000.
    steps: tuple[int, ...] = setting(())
    # A checkpoint folder to score (repeatable), with or instead of train_dir; its step is its training state's.
    checkpoints: tuple[Path, ...] = setting((), flag="--checkpoint", repeat=True, metavar="PATH")


@dataclass
class SelectSettings(SeriesSettings):
    """`kitbench select`: which checkpoints, on which validation suite, and how each is scored."""

    choice: CheckpointChoice


def validation_suites(task: str | None = None) -> list[str]:
    """The shipped validation suites (of `task`), by name."""
    paths = shipped_suites(task, (shipped.ROOT,)) if task else sorted((shipped.ROOT / "eval/suites").glob("*.toml"))
    return [p.stem for p in paths if load_suite(p).purpose == "validation"]


def check_validation_suite(suite: Suite) -> None:
    """Refuse a suite that is not for selection: a test suite, or a validation suite sharing a seed with a shipped
    test suite of its task."""
    where = suite.source or suite.name
    if suite.purpose != "validation":
        raise KitbenchError(
            f"suite {where} is a {suite.purpose} suite: checkpoints are chosen on a validation suite's seeds, never on "
            f"seeds a figure is scored on; valid choices: {', '.join(validation_suites(suite.task_id))} (or a suite "
            'file with purpose = "validation")'
        )
    for path in shipped_suites(suite.task_id, (shipped.ROOT,)):
        test = load_suite(path)
        shared = sorted(set(suite.seeds) & set(test.seeds)) if test.purpose == "test" else []
        if shared:
            raise KitbenchError(
                f"validation suite {where} shares {len(shared)} seed(s) with test suite {path.stem} (first "
                f"{shared[0]}); a validation suite's seeds must be disjoint from every test suite's"
            )


def _is_checkpoint(folder: Path) -> bool:
    return all((folder / name).is_file() for name in CHECKPOINT_FILES)


def _saved(train_dir: Path) -> dict[int, Path]:
    """The checkpoints a lerobot-train output folder holds, by step (`checkpoints/<step>/pretrained_model`; `last`
    is a link to one of them)."""
    folder = train_dir / "checkpoints"
    found = {}
    for step_dir in sorted(folder.iterdir()) if folder.is_dir() else []:
        model = step_dir / "pretrained_model"
        if step_dir.name.isdigit() and not step_dir.is_symlink() and _is_checkpoint(model):
            found[int(step_dir.name)] = model
    if not found:
        raise KitbenchError(
            f"no checkpoint in {train_dir} (looked for checkpoints/<step>/pretrained_model with "
            f"{' and '.join(CHECKPOINT_FILES)}); give a lerobot-train output folder or --checkpoint PATH"
        )
    return found


def _explicit(path: Path) -> tuple[int, Path]:
    for folder in (path, path / "pretrained_model"):
        if _is_checkpoint(folder):
            step = training_step(folder)
            if step is None:
                raise KitbenchError(
                    f"checkpoint {path} has no training step (no training_state/training_step.json beside it and "
                    "its folder is not named by a step); select scores checkpoints of a lerobot-train run"
                )
            return step, folder
    raise KitbenchError(
        f"no lerobot checkpoint at {path} (looked for {' and '.join(CHECKPOINT_FILES)} in it and in pretrained_model/)"
    )


def checkpoints(choice: CheckpointChoice) -> dict[int, Path]:
    """The checkpoints to score, by training step, in step order."""
    if choice.train_dir is None and not choice.checkpoints:
        raise KitbenchError("nothing to score: give a lerobot-train output folder (train_dir) or --checkpoint PATH")
    found: dict[int, Path] = {}
    if choice.train_dir is not None:
        saved = _saved(Path(choice.train_dir))
        missing = [s for s in choice.steps if s not in saved]
        if missing:
            raise KitbenchError(
                f"step {missing[0]} is not saved in {choice.train_dir}; valid choices: {', '.join(map(str, saved))}"
            )
        found = {s: saved[s] for s in (choice.steps or saved)}
    elif choice.steps:
        raise KitbenchError("--steps chooses among a train_dir's checkpoints; give the lerobot-train output folder")
    for path in choice.checkpoints:
        step, folder = _explicit(Path(path))
        if step in found and found[step].resolve() != folder.resolve():
            raise KitbenchError(f"two checkpoints of step {step}: {found[step]} and {folder}; score them apart")
        found[step] = folder
    return dict(sorted(found.items()))


def _mcnemar(a: dict, b: dict) -> float:
    from kitbench.evaluation.significance import mcnemar_p

    ok_a = {e["seed"]: e["success"] for e in a["per_episode"]}
    ok_b = {e["seed"]: e["success"] for e in b["per_episode"]}
    return mcnemar_p(sum(ok_a[s] and not ok_b[s] for s in ok_a), sum(ok_b[s] and not ok_a[s] for s in ok_a))


def summarise(found: dict[int, Path], reports: dict[str, dict], suite: Suite) -> dict:
    rows = [
        {"step": step, "checkpoint": str(path), "report": _name(step), **rate_row(reports[_name(step)])}
        for step, path in found.items()
    ]
    best = max(rows, key=lambda r: (r["rate"], r["step"]))  # ties: the later step
    last = rows[-1]
    overlap = best["ci95"][0] <= last["ci95"][1] and last["ci95"][0] <= best["ci95"][1]
    return {
        "suite": suite.source,
        "suite_name": suite.name,
        "episodes": len(suite.seeds),
        "rows": rows,
        "best_step": best["step"],
        "last_step": last["step"],
        "best_is_last": best is last,
        "best_overlaps_last": overlap,
        "best_vs_last_mcnemar_p": _mcnemar(reports[best["report"]], reports[last["report"]]),
    }


def verdict(summary: dict) -> str:
    rows = {r["step"]: r for r in summary["rows"]}
    best, last = rows[summary["best_step"]], rows[summary["last_step"]]
    head = f"best: step {best['step']}, {best['successes']}/{best['episodes']} ({best['rate']:.1%})"
    if summary["best_is_last"]:
        tied = [r["step"] for r in summary["rows"] if r["rate"] == best["rate"] and r is not best]
        return f"{head}: the last checkpoint is the best" + (
            f" (tied with step(s) {', '.join(map(str, tied))})" if tied else ""
        )
    overlap = "overlap" if summary["best_overlaps_last"] else "do not overlap"
    return (
        f"{head}; the last (step {last['step']}) {last['successes']}/{last['episodes']} ({last['rate']:.1%}): "
        f"their 95% intervals {overlap} (paired exact McNemar p {summary['best_vs_last_mcnemar_p']:.3g})"
    )


def markdown(summary: dict) -> str:
    lines = [
        f"# Checkpoint selection on {summary['suite_name']} ({summary['episodes']} seeds)",
        "",
        "| step | successes/episodes | rate | 95% Wilson CI | report |",
        "|---|---|---|---|---|",
    ]
    lines += [f"| {r['step']} | {rate_text(r)} | [{r['report']}]({r['report']}/report.md) |" for r in summary["rows"]]
    return "\n".join([*lines, "", verdict(summary) + ".", "", f"![success against training step]({SUMMARY}.png)", ""])


def _name(step: int) -> str:
    return f"{step:06d}"  # lerobot-train's own folder names, so they sort


def run_select(flags: dict[str, Any], progress: bool = True) -> int:
    from kitbench.evaluation.plots import success_against

    settings = declare.build(SelectSettings, flags)
    if settings.selection.suite_file is None:
        raise KitbenchError(f"give --suite, a validation suite; valid choices: {', '.join(validation_suites())}")
    flags["suite_file"] = shipped.find(settings.selection.suite_file, "suite")
    suite = load_suite(flags["suite_file"])
    check_validation_suite(suite)
    found = checkpoints(settings.choice)
    run = Path(settings.choice.train_dir or found[max(found)]).resolve()
    out = Path(settings.output.out or Path("outputs/select") / slug(f"{run.parent.name}_{run.name}"))
    check_folder(out, settings.output.overwrite, settings.output.resume, "checkpoint selection")
    shared = eval_flags(flags, SelectSettings)
    cells = [Cell(_name(s), cell_config(shared, out, _name(s), f"lerobot:{p}")) for s, p in found.items()]
    reports = run_cells(cells, settings.output.resume, progress)
    summary = summarise(found, reports, cells[0].config.suite)
    rates = summary["rows"]
    best = [r["step"] for r in rates].index(summary["best_step"])
    title = f"{suite.task} · {summary['suite_name']} · {summary['episodes']} episodes per checkpoint"
    success_against([r["step"] for r in rates], rates, out / f"{SUMMARY}.png", "training step", title, best)
    written = write_summary(out, SUMMARY, summary, markdown(summary))
    for r in summary["rows"]:
        print(f"step {r['step']}: {rate_text(r).replace(' | ', ', ')}")
    print(verdict(summary))
    print(f"table: {written[0]} (+ {written[1].name}, {SUMMARY}.png)")
    return 0
