"""From episode results to the report: the numbers (JSON), a readable page (Markdown) and where plots are.

Everything in `report.json` except its `timing` section depends only on the policy and the suite, so two runs
compare equal, whatever the number of workers.
"""

from __future__ import annotations

import json
from pathlib import Path

import kitbench
from kitbench.evaluation.episode import EpisodeResult
from kitbench.evaluation.outcomes import PHYSICS_ERROR
from kitbench.evaluation.stats import describe, rate
from kitbench.evaluation.suite import Suite
from kitbench.registration import task_entry

REPORT_VERSION = 1


def _timing_parts(timing: dict) -> str:
    """The wall time's parts, as `report.json`'s `timing` gives them (older reports have fewer)."""
    parts = (
        ("setup_seconds", "setup"),
        ("scoring_seconds", "episodes"),
        ("report_seconds", "report"),
        ("video_seconds", "videos"),
    )
    return ", ".join(f"{label} {timing[key]:.1f} s" for key, label in parts if key in timing)


def _per_group(results: list[EpisodeResult], id_key: str, name_key: str) -> list[dict]:
    """Success and criteria rates per value of `episode_config()[id_key]` (the task's `report_groups`)."""
    groups: dict = {}
    for r in results:
        groups.setdefault(r.config[id_key], []).append(r)
    rows = []
    for group_id in sorted(groups):
        rs = groups[group_id]
        row = {id_key: group_id, name_key: rs[0].config[name_key], **rate(sum(r.success for r in rs), len(rs))}
        for name in rs[0].criteria:
            row[name] = sum(r.criteria[name] for r in rs) / len(rs)
        rows.append(row)
    return rows


def build_report(suite: Suite, policy: str, results: list[EpisodeResult], control_timestep: float) -> dict:
    n = len(results)
    successes = [r for r in results if r.success]
    names = list(results[0].criteria) if results else []
    env_class = task_entry(suite.task).env_class
    # the task's categories in its stage order, then episodes the simulator could not finish
    categories = dict.fromkeys((*env_class.failure_categories, PHYSICS_ERROR), 0)
    for r in results:
        if r.failure is not None:
            categories[r.failure] = categories.get(r.failure, 0) + 1
    report = {
        "report_version": REPORT_VERSION,
        "kitbench_version": kitbench.__version__,
        "task": suite.task,
        "policy": policy,
        "suite": suite.to_dict(),
        "episodes": n,
        "success": rate(len(successes), n),
        "criteria": {name: rate(sum(r.criteria[name] for r in results), n) for name in names},
        "episode_length": describe(r.length for r in results),
        "steps_to_success": describe(r.steps_to_success for r in successes),
        "seconds_to_success": describe((r.steps_to_success or 0) * control_timestep for r in successes),
        "return": describe(r.episode_return for r in results),
        "return_by_outcome": {
            "success": describe(r.episode_return for r in successes),
            "failure": describe(r.episode_return for r in results if not r.success),
        },
        "failure_categories": categories,
        "per_episode": [r.to_dict() for r in results],
    }
    if env_class.report_groups is not None:
        id_key, name_key = env_class.report_groups
        report["report_groups"] = [id_key, name_key]
        report[f"per_{name_key}"] = _per_group(results, id_key, name_key)
    return report


def group_table(report: dict) -> tuple[str, str, list[dict]] | None:
    """The report's breakdown by the task's `report_groups` (id key, name key, rows), if it has one."""
    if "report_groups" not in report:
        return None
    id_key, name_key = report["report_groups"]
    return id_key, name_key, report[f"per_{name_key}"]


def without_timing(report: dict) -> dict:
    """The part of a report that must not change between runs (for comparing two evaluations)."""
    return {k: v for k, v in report.items() if k not in ("timing", "output")}


def write_json(report: dict, path: Path) -> None:
    partial = path.with_name(f".{path.name}.partial")
    partial.write_text(json.dumps(report, indent=1, sort_keys=False) + "\n")
    partial.replace(path)


def _pct(r: dict) -> str:
    lo, hi = r["ci95"]
    return f"{r['rate']:.1%} ({r['count']}/{r['episodes']}; 95% CI {lo:.1%}–{hi:.1%})"


def _dist_row(name: str, d: dict | None, unit: str = "") -> str:
    if d is None:
        return f"| {name} | – | – | – | – | – | – |"
    return (
        f"| {name} | {d['n']} | {d['mean']:.2f}{unit} | {d['median']:.2f}{unit} | {d['p10']:.2f}{unit} | "
        f"{d['p90']:.2f}{unit} | {d['min']:.2f}–{d['max']:.2f}{unit} |"
    )


def markdown(report: dict) -> str:
    suite = report["suite"]
    lines = [
        f"# {report['task']}: policy `{report['policy']}`",
        "",
        f"Suite `{suite['name']}`"
        + (f" ({suite['source']})" if suite.get("source") else "")
        + f": {report['episodes']} episodes, seeds {suite['seeds'][0]}…{suite['seeds'][-1]}, "
        f"obs `{suite['obs_mode']}`, control `{suite['control_mode']}`, reward `{suite['reward_mode']}`. "
        f"kitbench {report['kitbench_version']}.",
        "",
        f"**Success: {_pct(report['success'])}**",
        "",
        "## Success criteria (at the last step)",
        "",
        "| criterion | rate |",
        "|---|---|",
        *[f"| {name} | {_pct(r)} |" for name, r in report["criteria"].items()],
        "",
        "## Distributions",
        "",
        "| quantity | n | mean | median | p10 | p90 | range |",
        "|---|---|---|---|---|---|---|",
        _dist_row("episode length (steps)", report["episode_length"]),
        _dist_row("steps to success", report["steps_to_success"]),
        _dist_row("time to success (s, simulated)", report["seconds_to_success"]),
        _dist_row("return", report["return"]),
        _dist_row("return of successes", report["return_by_outcome"]["success"]),
        _dist_row("return of failures", report["return_by_outcome"]["failure"]),
        "",
        "## Failures by category",
        "",
        "| category | episodes |",
        "|---|---|",
        *[f"| {c} | {n} |" for c, n in report["failure_categories"].items()],
    ]
    table = group_table(report)
    if table is not None:
        id_key, name, rows = table
        crit = list(report["criteria"])
        lines += [
            "",
            f"## Per {name}",
            "",
            f"| id | {name} | episodes | success | 95% CI | " + " | ".join(crit) + " |",
            "|---|---|---|---|---|" + "---|" * len(crit),
        ]
        for row in rows:
            lo, hi = row["ci95"]
            lines.append(
                f"| {row[id_key]} | {row[name]} | {row['episodes']} | {row['rate']:.0%} | "
                f"{lo:.0%}–{hi:.0%} | " + " | ".join(f"{row[c]:.0%}" for c in crit) + " |"
            )
    errors = [e for e in report["per_episode"] if e.get("physics_error")]
    if errors:
        lines += ["", "## Physics errors", ""]
        lines += [f"- seed {e['seed']}: {e['physics_error']}" for e in errors]
    output = report.get("output", {})
    if output.get("videos") or output.get("video_error"):
        lines += ["", "## Videos", ""]
        lines += [
            f"- seed {v['seed']} ({'success' if v['success'] else 'failure: ' + str(v['failure'])}): "
            f"[{v['path']}]({v['path']})"
            for v in output.get("videos", [])
        ]
        if output.get("video_error"):
            lines.append(f"- videos could not be made: {output['video_error']}")
    if output.get("plots"):
        lines += ["", "## Plots", ""]
        lines += [f"![{Path(p).stem}]({p})" for p in output["plots"]]
    timing = report.get("timing")
    if timing:
        lines += [
            "",
            (
                f"Evaluated in {timing['seconds']:.1f} s wall time with {timing['workers']} worker(s), "
                f"{timing['episodes_per_minute']:.1f} episodes/min: " + _timing_parts(timing) + "."
            ),
        ]
    failures = [e for e in report["per_episode"] if not e["success"]]
    if failures:
        lines += [
            "",
            "## Failed seeds",
            "",
            ", ".join(f"{e['seed']} ({e['failure']})" for e in failures[:50]) + (" …" if len(failures) > 50 else ""),
        ]
    return "\n".join(lines) + "\n"
