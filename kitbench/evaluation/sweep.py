"""`kitbench sweep`: score one policy over a grid of execution settings on one suite.

`--grid KEY=V1,V2,...` (repeatable) gives a setting and its values; the grid is every combination, in the order
given. A key is `action_delay` (inference latency in control steps, `kitbench eval --action-delay`),
`temporal_ensemble` (on: `temporal_ensemble_coeff` = `ENSEMBLE_ON`, the original ACT work's; off: none), or
any `--policy-option` key of the policy (`n_action_steps`, `num_inference_steps`, `temporal_ensemble_coeff`, ...).

Each cell is an ordinary `kitbench eval` report in `<out>/<cell>/` (resumable; its provenance's `execution` holds
the settings in force), then `sweep.json`, `sweep.md` and `sweep.png` tabulate and plot success with its Wilson
interval per cell. A combination the policy's own config refuses (ACT ensembles only with n_action_steps=1, and
executes at most chunk_size actions of a chunk) is skipped, its one-line reason in the table; a grid every cell of
which is refused is refused.
"""

from __future__ import annotations

import itertools
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from kitbench import shipped
from kitbench.config import declare
from kitbench.config.declare import setting
from kitbench.errors import KitbenchError, one_line
from kitbench.evaluation.config import DELAY, ScoredPolicy
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
from kitbench.policies.ensemble import ENSEMBLE_OPTION

SUMMARY = "sweep"
ENSEMBLE = "temporal_ensemble"
ENSEMBLE_ON = 0.01  # the original ACT work's coefficient, as lerobot's ACT config notes
SWITCH = {"on": True, "off": False, True: True, False: False}
SHOWN = ("n_action_steps", ENSEMBLE_OPTION, "num_inference_steps", DELAY)  # execution settings the table reads back


def parse_axis(text: str) -> tuple[str, tuple]:
    """`KEY=V1,V2,...`, each value read as JSON (`5`, `0.01`, `null`), else as text (`on`)."""
    key, sep, raw = text.partition("=")
    values = [v.strip() for v in raw.split(",")]
    if not sep or not key.strip() or not all(values):
        raise KitbenchError(f"--grid {text!r} is not KEY=V1,V2,... (e.g. n_action_steps=1,10,50)")

    def value(v: str) -> object:
        try:
            return json.loads(v)
        except ValueError:
            return v

    parsed = tuple(value(v) for v in values)
    if len(set(map(repr, parsed))) != len(parsed):
        raise KitbenchError(f"--grid {text!r} repeats a value")
    return key.strip(), parsed


@dataclass
class SweepGrid:
    # A setting and its values (repeatable; the grid is every combination): n_action_steps=1,10,50,
    # temporal_ensemble=on,off, action_delay=0,1,2, or any --policy-option key.
    grid: tuple[tuple[str, tuple], ...] = setting((), repeat=True, parse=parse_axis, metavar="KEY=V1,V2,...")


@dataclass
class SweepSettings(SeriesSettings):
    """`kitbench sweep`: the grid, the suite, the policy and how each cell is scored."""

    axes: SweepGrid


def _check_axes(grid: tuple[tuple[str, tuple], ...], fixed: dict) -> None:
    """Refuse an empty grid, a key given twice or also fixed on the command line (`fixed`: the policy options and
    a delay given), and a value its key cannot take."""
    keys = [k for k, _ in grid]
    if not keys:
        raise KitbenchError("give at least one --grid KEY=V1,V2,... (e.g. --grid n_action_steps=1,10,50)")
    repeated = sorted({k for k in keys if keys.count(k) > 1})
    if repeated:
        raise KitbenchError(f"--grid {repeated[0]} is given twice; give its values once, comma-separated")
    for key in keys:
        twin = ENSEMBLE_OPTION if key == ENSEMBLE and ENSEMBLE_OPTION in {*fixed, *keys} else key
        if twin != key or key in fixed:
            given = "--action-delay" if key == DELAY else f"--policy-option {twin}"
            given = f"--grid {twin}" if twin != key and twin in keys else given
            raise KitbenchError(f"--grid {key} and {given} set the same setting; drop one")
    for key, values in grid:
        for v in values:
            if key == ENSEMBLE and v not in SWITCH:
                raise KitbenchError(f"--grid {ENSEMBLE} value {v!r}; valid choices: on, off")
            if key == DELAY:
                declare.leaves(ScoredPolicy)[DELAY].check(v)


def _cell_settings(cell: dict[str, Any], options: dict, delay: int = 0) -> dict[str, Any]:
    """A cell's grid values as an evaluation's settings: its policy options (over the command line's) and delay
    (`delay`: the command line's)."""
    mine = dict(options)
    for key, value in cell.items():
        if key == ENSEMBLE:
            mine[ENSEMBLE_OPTION] = ENSEMBLE_ON if SWITCH[value] else None
        elif key != DELAY:
            mine[key] = value
    return {"policy_options": tuple(mine.items()), DELAY: cell.get(DELAY, delay)}


def cell_name(cell: dict[str, Any]) -> str:
    return "_".join(f"{k}={slug(str(v).lower())}" for k, v in cell.items())


def refusals(spec: str, cells: list[dict], options: dict) -> dict[str, str]:
    """Why the policy refuses each cell it refuses (its config's own checks, run by loading it with the cell's
    options once per distinct set), by cell name."""
    from kitbench.policies.registry import make_policy

    checked: dict[tuple, str | None] = {}
    found = {}
    for cell in cells:
        mine = _cell_settings(cell, options)["policy_options"]
        key = tuple((k, json.dumps(v)) for k, v in mine)
        if key not in checked:
            try:
                make_policy(spec, "cpu", dict(mine))
                checked[key] = None
            except KitbenchError as exc:
                checked[key] = one_line(exc, typed=False)
        reason = checked[key]
        if reason is not None:
            found[cell_name(cell)] = reason
    return found


def summarise(grid, cells: list[dict], reports: dict[str, dict], skipped: dict[str, str], suite) -> dict:
    rows = []
    for cell in cells:
        name = cell_name(cell)
        row: dict[str, Any] = {"cell": name, "settings": cell}
        if name in skipped:
            row.update(status="skipped", reason=skipped[name])
        else:
            ran = reports[name].get("provenance", {}).get("execution", {})
            row.update(status="scored", execution={k: ran.get(k) for k in SHOWN if k in ran}, **rate_row(reports[name]))
        rows.append(row)
    scored = [r for r in rows if r["status"] == "scored"]
    best = max(scored, key=lambda r: r["rate"])  # ties: the first in grid order
    return {
        "policy": next(iter(reports.values()))["policy"],
        "suite": suite.source,
        "suite_name": suite.name,
        "episodes": len(suite.seeds),
        "grid": {k: list(v) for k, v in grid},
        "rows": rows,
        "best_cell": best["cell"],
    }


def markdown(summary: dict) -> str:
    keys = list(summary["grid"])
    lines = [
        f"# Execution settings: {summary['policy']} on {summary['suite_name']} ({summary['episodes']} seeds)",
        "",
        "| " + " | ".join(keys) + " | successes/episodes | rate | 95% Wilson CI | report |",
        "|" + "---|" * (len(keys) + 4),
    ]
    for r in summary["rows"]:
        values = " | ".join(str(r["settings"][k]) for k in keys)
        if r["status"] == "skipped":
            lines.append(f"| {values} | – | – | – | skipped: {r['reason']} |")
        else:
            lines.append(f"| {values} | {rate_text(r)} | [{r['cell']}]({r['cell']}/report.md) |")
    best = next(r for r in summary["rows"] if r["cell"] == summary["best_cell"])
    lines += ["", f"Highest: {best['cell']}, {rate_text(best).replace(' | ', ', ')}.", ""]
    return "\n".join([*lines, f"![success per setting]({SUMMARY}.png)", ""])


def run_sweep(flags: dict[str, Any], progress: bool = True) -> int:
    from kitbench.evaluation.plots import success_against

    settings = declare.build(SweepSettings, flags)
    options = dict(settings.policy.policy_options)
    grid = settings.axes.grid
    delay = settings.policy.action_delay
    _check_axes(grid, {**options, **({DELAY: delay} if DELAY in flags else {})})
    if settings.selection.suite_file is None:
        raise KitbenchError("give --suite, the suite every cell is scored on (eval/suites/<name>.toml or its name)")
    flags["suite_file"] = shipped.find(settings.selection.suite_file, "suite")
    spec = settings.policy.policy
    cells = [
        dict(zip([k for k, _ in grid], values, strict=True)) for values in itertools.product(*(v for _, v in grid))
    ]
    skipped = refusals(spec, cells, options)
    if len(skipped) == len(cells):
        raise KitbenchError(f"every cell of the grid is refused; the first: {next(iter(skipped.values()))}")
    out = Path(settings.output.out or Path("outputs/sweep") / slug(spec)[-80:])
    check_folder(out, settings.output.overwrite, settings.output.resume, "sweep")
    shared = eval_flags(flags, SweepSettings)
    shared.pop("policy_options", None)
    to_run = [
        Cell(cell_name(c), cell_config(shared, out, cell_name(c), spec, **_cell_settings(c, options, delay)))
        for c in cells
        if cell_name(c) not in skipped
    ]
    reports = run_cells(to_run, settings.output.resume, progress)
    summary = summarise(grid, cells, reports, skipped, to_run[0].config.suite)
    scored = [r for r in summary["rows"] if r["status"] == "scored"]
    best = [r["cell"] for r in scored].index(summary["best_cell"])
    title = f"{summary['policy']} · {summary['suite_name']} · {summary['episodes']} episodes per cell"
    labels = [" · ".join(str(r["settings"][k]) for k in summary["grid"]) for r in scored]
    success_against(labels, scored, out / f"{SUMMARY}.png", " · ".join(summary["grid"]), title, best)
    written = write_summary(out, SUMMARY, summary, markdown(summary))
    for r in summary["rows"]:
        shown = rate_text(r).replace(" | ", ", ") if r["status"] == "scored" else f"skipped: {r['reason']}"
        print(f"{r['cell']}: {shown}")
    print(f"table: {written[0]} (+ {written[1].name}, {SUMMARY}.png)")
    return 0
