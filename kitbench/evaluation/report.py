"""From episode results to the report: the numbers (JSON), a readable page (Markdown) and where plots are.

Everything in `report.json` except its `timing` section and its `provenance` (how and where it ran:
`kitbench.evaluation.provenance`) depends only on the policy and the suite, so two runs compare equal, whatever
the number of workers.

`success` is the suite's headline metric (`headline`: `success_once` or `success_at_end`, see
`kitbench.evaluation.suite`); both are reported beside it, overall and per group. A robustness suite adds
`robustness`: each perturbation and level scored on the same seeds, with its difference from the nominal run and
an exact McNemar test on the seeds (paired: the same seed nominal and perturbed).
"""

from __future__ import annotations

import json
from pathlib import Path

import kitbench
from kitbench.evaluation.episode import EpisodeResult
from kitbench.evaluation.outcomes import PHYSICS_ERROR
from kitbench.evaluation.significance import mcnemar_p
from kitbench.evaluation.stats import describe, rate
from kitbench.evaluation.suite import Suite
from kitbench.registration import task_entry

# 2: `headline`, `success_once`, `success_at_end` (overall, per group, per episode), suite `settle_steps` and
# `perturbations`, `robustness`
# 3: per episode `initial` (the task's measurements after the reset); `measurements` (each at the start and the end)
# 4: `provenance` (the weights, execution settings, suite digest, software, machine and command)
REPORT_VERSION = 4


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
        row["success_once"] = rate(sum(r.success_once for r in rs), len(rs))
        row["success_at_end"] = rate(sum(r.success_at_end for r in rs), len(rs))
        for name in rs[0].criteria:
            row[name] = sum(r.criteria[name] for r in rs) / len(rs)
        rows.append(row)
    return rows


def _categories(env_class, results: list[EpisodeResult]) -> dict[str, int]:
    """Failures by category: the task's categories in its stage order, then episodes the simulator could not
    finish."""
    categories = dict.fromkeys((*env_class.failure_categories, PHYSICS_ERROR), 0)
    for r in results:
        if r.failure is not None:
            categories[r.failure] = categories.get(r.failure, 0) + 1
    return categories


def _condition(name: str, level: float, results: list[EpisodeResult], nominal: list[EpisodeResult], env_class) -> dict:
    """One perturbation at one level: its rates, failures, and how it differs from the nominal run seed by seed."""
    from kitbench.perturbations import PERTURBATIONS

    n = len(results)
    by_seed = {r.seed: r for r in nominal}
    lost = sum(1 for r in results if by_seed[r.seed].success and not r.success)
    gained = sum(1 for r in results if r.success and not by_seed[r.seed].success)
    success = rate(sum(r.success for r in results), n)
    return {
        "perturbation": name,
        "level": level,
        "unit": PERTURBATIONS[name].unit,
        "nominal_level": PERTURBATIONS[name].nominal_level,
        "description": PERTURBATIONS[name].description,
        "episodes": n,
        "success": success,
        "success_once": rate(sum(r.success_once for r in results), n),
        "success_at_end": rate(sum(r.success_at_end for r in results), n),
        "criteria": {c: rate(sum(r.criteria[c] for r in results), n) for c in (results[0].criteria if n else {})},
        "failure_categories": _categories(env_class, results),
        # seeds that succeed nominal and fail perturbed, and the other way round; only these discordant seeds
        # carry evidence of a difference (exact McNemar test)
        "vs_nominal": {
            "difference": success["rate"] - sum(r.success for r in nominal) / max(len(nominal), 1),
            "seeds_lost": lost,
            "seeds_gained": gained,
            "p_value": mcnemar_p(lost, gained),
        },
        "per_episode": [
            {
                "seed": r.seed,
                "success": r.success,
                "success_once": r.success_once,
                "success_at_end": r.success_at_end,
                "failure": r.failure,
                "physics_error": r.physics_error,
            }
            for r in results
        ],
    }


def measurements(results: list[EpisodeResult]) -> dict:
    """Each scalar measurement the task reports (errors, tilt, ...; not its booleans) at the start and the end of
    the episodes, and at the end of the failures: how far a policy moved what the success test measures."""
    names = [k for k, v in (results[0].final if results else {}).items() if isinstance(v, float)]
    failures = [r for r in results if not r.success]
    return {
        name: {
            "start": describe(r.initial[name] for r in results if name in r.initial),
            "end": describe(r.final[name] for r in results if name in r.final),
            "end_of_failures": describe(r.final[name] for r in failures if name in r.final),
        }
        for name in names
    }


def build_report(
    suite: Suite,
    policy: str,
    results: list[EpisodeResult],
    control_timestep: float,
    perturbed: dict[tuple[str, float], list[EpisodeResult]] | None = None,
) -> dict:
    n = len(results)
    successes = [r for r in results if r.success]
    names = list(results[0].criteria) if results else []
    env_class = task_entry(suite.task_id).env_class
    categories = _categories(env_class, results)
    report = {
        "report_version": REPORT_VERSION,
        "kitbench_version": kitbench.__version__,
        "task": suite.task,
        "policy": policy,
        "suite": suite.to_dict(),
        "episodes": n,
        "headline": suite.headline,
        "success": rate(len(successes), n),
        "success_once": rate(sum(r.success_once for r in results), n),
        "success_at_end": rate(sum(r.success_at_end for r in results), n),
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
        "measurements": measurements(results),
        "per_episode": [r.to_dict() for r in results],
    }
    if env_class.report_groups is not None:
        id_key, name_key = env_class.report_groups
        report["report_groups"] = [id_key, name_key]
        report[f"per_{name_key}"] = _per_group(results, id_key, name_key)
    if suite.perturbations:
        perturbed = perturbed or {}
        report["robustness"] = [
            _condition(name, level, perturbed[(name, level)], results, env_class)
            for condition in suite.conditions[1:]
            if condition is not None
            for name, level in [condition]
        ]
    return report


def group_table(report: dict) -> tuple[str, str, list[dict]] | None:
    """The report's breakdown by the task's `report_groups` (id key, name key, rows), if it has one."""
    if "report_groups" not in report:
        return None
    id_key, name_key = report["report_groups"]
    return id_key, name_key, report[f"per_{name_key}"]


def without_timing(report: dict) -> dict:
    """The part of a report that must not change between runs (for comparing two evaluations): its provenance
    names the command, the machine and the batch size, which may differ while the scores do not."""
    return {k: v for k, v in report.items() if k not in ("timing", "output", "provenance")}


def write_json(report: dict, path: Path) -> None:
    partial = path.with_name(f".{path.name}.partial")
    partial.write_text(json.dumps(report, indent=1, sort_keys=False) + "\n")
    partial.replace(path)


def _pct(r: dict) -> str:
    lo, hi = r["ci95"]
    return f"{r['rate']:.1%} ({r['count']}/{r['episodes']}; 95% CI {lo:.1%}–{hi:.1%})"


def _spread(d: dict | None) -> str:
    return "–" if d is None else f"{d['median']:.3g} ({d['p10']:.3g}–{d['p90']:.3g})"


def _dist_row(name: str, d: dict | None, unit: str = "") -> str:
    if d is None:
        return f"| {name} | – | – | – | – | – | – |"
    return (
        f"| {name} | {d['n']} | {d['mean']:.2f}{unit} | {d['median']:.2f}{unit} | {d['p10']:.2f}{unit} | "
        f"{d['p90']:.2f}{unit} | {d['min']:.2f}–{d['max']:.2f}{unit} |"
    )


def _headline_text(report: dict) -> str:
    headline = report.get("headline", "success_once")
    settle = report["suite"].get("settle_steps", 0)
    if headline == "success_at_end":
        return f"the headline is success_at_end: episodes run {settle} steps past their first success"
    return "the headline is success_once: an episode ends at its first success"


def _short(r: dict | None) -> str:
    """A rate with its interval, compactly (a table cell)."""
    if r is None:
        return "–"
    lo, hi = r["ci95"]
    return f"{r['rate']:.0%} ({lo:.0%}–{hi:.0%})"


def _robustness_lines(report: dict) -> list[str]:
    nominal = report["success"]
    lines = [
        "",
        "## Robustness",
        "",
        (
            "The suite's seeds under each perturbation, one at a time; Δ is the change in success from the nominal "
            "run, p an exact McNemar test on the seeds that changed outcome."
        ),
        "",
        "| perturbation | level | success (95% CI) | Δ | seeds lost / gained | p | main failure |",
        "|---|---|---|---|---|---|---|",
        f"| nominal | – | {_short(nominal)} | – | – | – | {_main_failure(report['failure_categories'])} |",
    ]
    for c in report["robustness"]:
        vs = c["vs_nominal"]
        lines.append(
            f"| {c['perturbation']} | {c['level']:g} {c['unit']} | {_short(c['success'])} | "
            f"{vs['difference']:+.0%} | {vs['seeds_lost']} / {vs['seeds_gained']} | {vs['p_value']:.3g} | "
            f"{_main_failure(c['failure_categories'])} |"
        )
    lines += ["", "What each perturbation does:", ""]
    for name in dict.fromkeys(c["perturbation"] for c in report["robustness"]):
        first = next(c for c in report["robustness"] if c["perturbation"] == name)
        lines.append(f"- `{name}` ({first['unit']}): {first['description']}")
    return lines


def _cameras_text(suite: dict) -> str:
    """The cameras' size and view where the suite set them (the task's own otherwise)."""
    parts = [
        f"{label} `{suite[key]}`"
        for key, label in (("camera_size", "cameras"), ("camera_view", "view"))
        if suite.get(key)
    ]
    return (" (" + ", ".join(parts) + ")") if parts else ""


def _main_failure(categories: dict[str, int]) -> str:
    worst = max(categories.items(), key=lambda kv: kv[1], default=("", 0))
    return f"{worst[0]} ({worst[1]})" if worst[1] else "–"


def _provenance_lines(found: dict) -> list[str]:
    """The short provenance block of report.md (report.json has all of it)."""
    lines = ["", "## Provenance", ""]
    checkpoint = found["policy"].get("checkpoint")
    if checkpoint:
        step = checkpoint.get("training_step")
        lines.append(
            f"- weights: `{checkpoint['path']}`, sha256 `{checkpoint['sha256'][:16]}`"
            + ("" if step is None else f", training step {step}")
        )
        data = checkpoint.get("dataset")
        if data:
            extra = [f"root `{data['root']}`"] if data.get("root") else []
            extra += [f"{data['episodes']} episodes"] if data.get("episodes") is not None else []
            extra += [f"episodes sha256 `{data['episodes_sha256'][:16]}`"] if data.get("episodes_sha256") else []
            lines.append(f"- trained on `{data.get('repo_id')}`" + (f" ({', '.join(extra)})" if extra else ""))
    execution = {k: v for k, v in found["execution"].items() if k != "policy_options"}
    options = found["execution"].get("policy_options") or {}
    lines.append(
        "- execution: "
        + ", ".join(f"{k} {v}" for k, v in execution.items() if v is not None)
        + ("; options " + ", ".join(f"`{k}={v}`" for k, v in options.items()) if options else "")
    )
    lines.append(f"- suite digest `{found['suite']['digest'][:16]}`")
    lines.append("- software: " + ", ".join(f"{k} {v}" for k, v in found["software"].items() if v is not None))
    if found.get("vulkan"):
        drivers = "; ".join(found["vulkan"]["drivers"].values()) or "none listed"
        lines.append(f"- Vulkan device {found['vulkan']['device']} (drivers: {drivers})")
    machine = found["machine"]
    lines.append(
        f"- machine: {machine['cpu']}, {machine['cores']} cores" + (f", GPU {machine['gpu']}" if machine["gpu"] else "")
    )
    if found.get("source"):
        source = found["source"]
        lines.append(
            f"- kitbench at git `{source['git_commit'][:12]}`" + (" (with changes)" if source["dirty"] else "")
        )
    lines.append(f"- command: `{found['command']}`")
    return lines


def markdown(report: dict) -> str:
    suite = report["suite"]
    lines = [
        f"# {report['task']}: policy `{report['policy']}`",
        "",
        f"Suite `{suite['name']}`"
        + (f" ({suite['source']})" if suite.get("source") else "")
        + f": {report['episodes']} episodes, seeds {suite['seeds'][0]}…{suite['seeds'][-1]}, "
        f"robot `{suite.get('robot', '?')}`, obs `{suite['obs_mode']}`{_cameras_text(suite)}, "
        f"control `{suite['control_mode']}`, "
        f"reward `{suite['reward_mode']}`. "
        f"kitbench {report['kitbench_version']}.",
        "",
        *(
            [
                (
                    f"Partial: the first {report['partial']['episodes']} of the suite's "
                    f"{report['partial']['suite_episodes']} seeds (the run stopped there; `--resume` scores on)."
                ),
                "",
            ]
            if report.get("partial")
            else []
        ),
        *(
            [
                f"Policy options for this run: {', '.join(f'`{k}={v}`' for k, v in report['policy_options'].items())}.",
                "",
            ]
            if report.get("policy_options")
            else []
        ),
        f"**Success: {_pct(report['success'])}** ({_headline_text(report)})",
        "",
        f"- success_once (successful at any step): {_pct(report['success_once'])}",
        f"- success_at_end (successful at the last step): {_pct(report['success_at_end'])}",
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
    if report.get("measurements"):
        lines += [
            "",
            "## The task's measurements at the start and the end",
            "",
            "| measurement | start, median (p10–p90) | end | end of failures |",
            "|---|---|---|---|",
            *[
                f"| {name} | " + " | ".join(_spread(m[when]) for when in ("start", "end", "end_of_failures")) + " |"
                for name, m in report["measurements"].items()
            ],
        ]
    table = group_table(report)
    if table is not None:
        id_key, name, rows = table
        crit = list(report["criteria"])
        lines += [
            "",
            f"## Per {name}",
            "",
            f"| id | {name} | episodes | success | 95% CI | success_once | success_at_end | " + " | ".join(crit) + " |",
            "|---|---|---|---|---|---|---|" + "---|" * len(crit),
        ]
        for row in rows:
            lo, hi = row["ci95"]
            lines.append(
                f"| {row[id_key]} | {row[name]} | {row['episodes']} | {row['rate']:.0%} | "
                f"{lo:.0%}–{hi:.0%} | {_short(row.get('success_once'))} | {_short(row.get('success_at_end'))} | "
                + " | ".join(f"{row[c]:.0%}" for c in crit)
                + " |"
            )
    if report.get("robustness"):
        lines += _robustness_lines(report)
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
    if report.get("provenance"):
        lines += _provenance_lines(report["provenance"])
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
