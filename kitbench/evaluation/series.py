"""A series of evaluations written into one folder, each an ordinary `kitbench eval` report in `<out>/<name>/` with
its journal and provenance: what `kitbench select` (one report per checkpoint) and `kitbench sweep` (one per
setting) run, and the summary rows they tabulate.

`--resume` continues a series a kill or a SIGTERM stopped: a finished report is kept (once checked to be of the same
weights, seeds and execution settings), an interrupted one is continued from its journal (`kitbench eval --resume`),
a missing one is scored. Without `--resume` or `--overwrite`, a folder that holds anything is refused.
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from kitbench.config import declare
from kitbench.engine.config import ExecutorConfig
from kitbench.errors import KitbenchError
from kitbench.evaluation.config import EvalConfig, ReportSettings, ScoredPolicy, Selection, eval_config
from kitbench.evaluation.journal import EvalJournal
from kitbench.evaluation.output import REPORT_JSON
from kitbench.evaluation.provenance import checkpoint_files
from kitbench.evaluation.report import write_json
from kitbench.evaluation.runner import run_eval


@dataclass
class SeriesSettings:
    """What every report of a series shares with `kitbench eval`: the suite and its first N seeds, how the policy
    runs, where episodes run, and the folder (`out`: the series'; each report gets a folder in it)."""

    selection: Selection
    policy: ScoredPolicy
    executor: ExecutorConfig
    output: ReportSettings


def eval_flags(flags: dict[str, Any], kind: type) -> dict[str, Any]:
    """The flags of `kitbench eval` among a series command's (`kind`: its settings class)."""
    shared = declare.leaves(SeriesSettings)
    return {k: v for k, v in flags.items() if k in shared and k in declare.leaves(kind)}


def check_folder(out: Path, overwrite: bool, resume: bool, what: str) -> None:
    """Refuse a series folder that is a file, or that holds something (unless `resume` or `overwrite`), before
    anything is written."""
    if out.exists() and not out.is_dir():
        raise KitbenchError(f"{out} is a file; --out must be a folder (new, empty, or a {what} with --overwrite)")
    if resume and overwrite:
        raise KitbenchError("--resume and --overwrite exclude each other: continue the series, or score it again")
    if out.is_dir() and any(out.iterdir()) and not (resume or overwrite):
        raise KitbenchError(
            f"{out} holds a {what} already; continue it with --resume, or pass --overwrite to score it again"
        )


@dataclass
class Cell:
    """One report of a series: its folder's name and the evaluation that writes it."""

    name: str
    config: EvalConfig


def cell_config(flags: dict[str, Any], out: Path, name: str, policy: str, **settings: Any) -> EvalConfig:
    """The evaluation of one report: the command's eval flags, `policy`, `settings` (policy options, delay) on
    top, written to `out/name` (`--resume`: only where a journal waits; `--overwrite`: replaced)."""
    folder = out / name
    config = eval_config({**flags, "policy": policy, "out": folder, "resume": False, **settings})
    if flags.get("resume") and EvalJournal(folder).exists():
        config = config.replace(resume=True)
    return config


def _finished_differences(report: dict, config: EvalConfig) -> list[str]:
    """How a finished report differs from what `config` would score, one phrase each (empty: it stands)."""
    found = []
    if report.get("policy") != config.policy.policy:
        found.append(f"policy: report {report.get('policy')!r}, now {config.policy.policy!r}")
    if report["suite"]["name"] != config.suite.name:
        found.append(f"suite: report {report['suite']['name']!r}, now {config.suite.name!r}")
    if list(report["suite"]["seeds"]) != list(config.suite.seeds):
        found.append(f"seeds: report {len(report['suite']['seeds'])}, now {len(config.suite.seeds)}")
    provenance = report.get("provenance") or {}
    weights = (provenance.get("policy") or {}).get("checkpoint")
    if weights and (not Path(weights["path"]).is_dir() or checkpoint_files(Path(weights["path"])) != weights["files"]):
        found.append(f"checkpoint {weights['path']}: its files changed since the report")
    ran = provenance.get("execution") or {}
    now = {
        "policy_options": dict(config.policy.policy_options),
        "action_delay": config.policy.action_delay,
        "batch_size": config.policy.batch_size,
    }
    found += [
        f"{k}: report {ran.get(k)!r}, now {v!r}" for k, v in now.items() if json.loads(json.dumps(v)) != ran.get(k)
    ]
    return found


def score(cell: Cell, resume: bool, progress: bool = True) -> dict:
    """The cell's report: kept when `resume` finds it finished and of these settings, else scored (continued from
    its journal where one waits)."""
    folder = cell.config.out
    if resume and (folder / REPORT_JSON).is_file() and not EvalJournal(folder).exists():
        report = json.loads((folder / REPORT_JSON).read_text())
        differences = _finished_differences(report, cell.config)
        if differences:
            raise KitbenchError(
                f"cannot resume {folder}: " + "; ".join(differences) + " (pass --overwrite to score it again)"
            )
        return report
    return run_eval(cell.config, progress=progress)


def run_cells(cells: list[Cell], resume: bool, progress: bool = True) -> dict[str, dict]:
    """Each cell's report by name, scored in order, a line on stderr as each is done."""
    reports = {}
    for i, cell in enumerate(cells, 1):
        report = score(cell, resume, progress)
        s = report["success"]
        print(
            f"[{i}/{len(cells)}] {cell.name}: {s['count']}/{s['episodes']} "
            f"({s['rate']:.1%}, 95% CI {s['ci95'][0]:.1%}–{s['ci95'][1]:.1%})",
            file=sys.stderr,
        )
        reports[cell.name] = report
    return reports


def rate_row(report: dict) -> dict:
    """A summary row's scores: the headline's successes of the episodes, the rate and its Wilson interval."""
    s = report["success"]
    return {
        "successes": s["count"],
        "episodes": s["episodes"],
        "rate": s["rate"],
        "ci95": s["ci95"],
        "headline": report.get("headline", "success_once"),
    }


def rate_text(row: dict) -> str:
    return f"{row['successes']}/{row['episodes']} | {row['rate']:.1%} | {row['ci95'][0]:.1%}–{row['ci95'][1]:.1%}"


def write_summary(out: Path, stem: str, summary: dict, markdown: str) -> list[Path]:
    """`<stem>.md` then `<stem>.json` (last: a JSON summary means the table beside it is complete)."""
    md = out / f"{stem}.md"
    partial = md.with_name(f".{md.name}.partial")
    partial.write_text(markdown)
    partial.replace(md)
    write_json(summary, out / f"{stem}.json")
    return [md, out / f"{stem}.json"]


def slug(text: str) -> str:
    """A folder name from a setting's text."""
    return "".join(c if c.isalnum() or c in "-_.=" else "_" for c in text).strip("_.") or "_"
