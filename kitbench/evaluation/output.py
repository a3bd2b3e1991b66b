"""What an evaluation leaves in its report folder: the names of the files there, the report (report.json,
report.md, plots) written into it, and the lines `kitbench eval` prints about it."""

from __future__ import annotations

from pathlib import Path

from kitbench.evaluation.episode import EpisodeResult
from kitbench.evaluation.suite import Suite

REPORT_JSON, REPORT_MD, PLOTS_DIR, VIDEOS_DIR = "report.json", "report.md", "plots", "videos"


def write_report(
    suite: Suite,
    policy: str,
    results: list[EpisodeResult],
    timestep: float,
    out: Path,
    perturbed: dict[tuple[str, float], list[EpisodeResult]] | None = None,
    policy_options: dict | None = None,
) -> dict:
    from kitbench.evaluation.plots import write_plots
    from kitbench.evaluation.report import build_report

    report = build_report(suite, policy, results, timestep, perturbed)
    if policy_options:
        report["policy_options"] = dict(policy_options)
    report["output"] = {"videos": []}
    report["output"]["plots"] = [str(p.relative_to(out)) for p in write_plots(report, out / PLOTS_DIR)]
    return report


def save_report(report: dict, out: Path) -> None:
    from kitbench.evaluation.report import markdown, write_json

    (out / REPORT_MD).write_text(markdown(report))
    write_json(report, out / REPORT_JSON)  # last: a report.json means the report.md beside it is complete


def summary_lines(report: dict, out: Path) -> list[str]:
    s = report["success"]
    lines = [
        (
            f"{report['task']} · {report['policy']} · {report['episodes']} episodes: success {s['rate']:.1%} "
            f"(95% CI {s['ci95'][0]:.1%}–{s['ci95'][1]:.1%}; {report.get('headline', 'success_once')})"
        )
    ]
    if report.get("headline") == "success_at_end":
        lines.append(f"  success_once: {report['success_once']['rate']:.1%}")
    for name, r in report["criteria"].items():
        lines.append(f"  {name}: {r['rate']:.1%}")
    failures = {k: v for k, v in report["failure_categories"].items() if v}
    if failures:
        lines.append("  failures: " + ", ".join(f"{k} {v}" for k, v in failures.items()))
    lines.extend(
        f"  {c['perturbation']} {c['level']:g} {c['unit']}: {c['success']['rate']:.1%} "
        f"({c['vs_nominal']['difference']:+.1%}, p {c['vs_nominal']['p_value']:.2g})"
        for c in report.get("robustness", [])
    )
    if report.get("partial"):
        lines.append(
            f"  stopped after the first {report['partial']['episodes']} of the suite's "
            f"{report['partial']['suite_episodes']} seeds: --resume scores on (the journal is kept)"
        )
    lines.append(
        f"  report: {out / REPORT_MD} (+ {REPORT_JSON}, {len(report['output']['plots'])} plots, "
        f"{len(report['output']['videos'])} videos)"
    )
    return lines
