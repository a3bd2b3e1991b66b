"""PNG plots of a report (matplotlib, no display needed)."""

from __future__ import annotations

from pathlib import Path

from kitbench.evaluation.report import group_table


def _figure(width: float = 6.0, height: float = 3.6, **grid):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt, *plt.subplots(figsize=(width, height), dpi=100, **grid)


def error_bars(rates: list[dict]) -> list[list[float]]:
    """matplotlib's `yerr` (below, above) for rates as `stats.rate` writes them, clipped at 0: an interval's
    ends may carry rounding error past the rate (files written before `wilson_interval` made 0/N and N/N exact
    hold 1.7e-18 at 0/200), and matplotlib refuses a negative error bar."""
    return [[max(0.0, r["rate"] - r["ci95"][0]) for r in rates], [max(0.0, r["ci95"][1] - r["rate"]) for r in rates]]


def _rates(ax, labels, rows):
    rates = [r["rate"] for r in rows]
    ax.bar(range(len(rows)), rates, yerr=error_bars(rows), capsize=3, color="#4c72b0")
    ax.set_xticks(
        range(len(rows)), labels, rotation=45 if len(rows) > 6 else 0, ha="right" if len(rows) > 6 else "center"
    )
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("rate (95% Wilson CI)")


def draw_histogram(ax, ok: list, bad: list, xlabel: str) -> None:
    """Successes and failures stacked, counts on whole-number ticks, the legend beside the bars (never over
    them), and a note instead of an empty frame when there is nothing to show (e.g. time to success for a
    policy that never succeeds)."""
    from matplotlib.ticker import MaxNLocator

    data, labels = [d for d in (ok, bad) if d], [lbl for d, lbl in ((ok, "success"), (bad, "failure")) if d]
    if data:
        colors = {"success": "#55a868", "failure": "#c44e52"}
        ax.hist(data, bins=20, stacked=True, label=labels, color=[colors[lbl] for lbl in labels])
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    else:
        ax.text(0.5, 0.5, "no episode to show", ha="center", va="center", transform=ax.transAxes, color="0.4")
    ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel(xlabel)
    ax.set_ylabel("episodes")


def write_plots(report: dict, folder: Path) -> list[Path]:
    """One PNG per view: success and criteria, episode length, return, time to success, per group (the task's
    `report_groups`, e.g. per shape)."""
    folder.mkdir(parents=True, exist_ok=True)
    title = f"{report['task']} · {report['policy']} · {report['episodes']} episodes"
    written = []

    plt, fig, ax = _figure()
    # both success metrics (older reports have only the one), then the criteria
    metrics = [m for m in ("success_once", "success_at_end") if m in report] or ["success"]
    rows = [report[m] for m in metrics] + list(report["criteria"].values())
    _rates(ax, [*metrics, *report["criteria"]], rows)
    ax.set_title(f"{title} · headline {report.get('headline', 'success_once')}", fontsize=9)
    written.append(_save(plt, fig, folder / "success.png"))

    episodes = report["per_episode"]
    for name, key, xlabel in (
        ("episode_length", "length", "control steps"),
        ("return", "episode_return", "return"),
        ("steps_to_success", "steps_to_success", "control steps to first success"),
    ):
        plt, fig, ax = _figure()
        ok = [e[key] for e in episodes if e["success"] and e[key] is not None]
        bad = [e[key] for e in episodes if not e["success"] and e[key] is not None]
        draw_histogram(ax, ok, bad, xlabel)
        ax.set_title(title, fontsize=9)
        written.append(_save(plt, fig, folder / f"{name}.png"))

    table = group_table(report)
    if table is not None:
        id_key, name, rows = table
        plt, fig, ax = _figure(8.0, 3.8)
        _rates(ax, [f"{r[id_key]} {r[name]}" for r in rows], rows)
        ax.set_title(f"success by {name} · {title}", fontsize=9)
        written.append(_save(plt, fig, folder / f"per_{name}.png"))
    if report.get("robustness"):
        written.append(_robustness(report, folder / "robustness.png", title))
    return written


def _robustness(report: dict, path: Path, title: str) -> Path:
    """Success against level, one panel per perturbation, the nominal rate and its interval as a band."""
    names = list(dict.fromkeys(c["perturbation"] for c in report["robustness"]))
    columns = min(3, len(names))
    rows = (len(names) + columns - 1) // columns
    plt, fig, axes = _figure(3.2 * columns, 2.6 * rows + 0.4, nrows=rows, ncols=columns, squeeze=False)
    axes = list(axes.flat)
    nominal = report["success"]
    for ax, name in zip(axes, names, strict=False):
        conditions = sorted((c for c in report["robustness"] if c["perturbation"] == name), key=lambda c: c["level"])
        # the nominal run sits at the level that changes nothing (0, or 1 for a factor), so each panel reads as
        # success against the size of the change
        points = sorted(
            [(conditions[0].get("nominal_level", 0.0), nominal), *((c["level"], c["success"]) for c in conditions)],
            key=lambda p: p[0],
        )
        levels = [p[0] for p in points]
        rates = [p[1]["rate"] for p in points]
        ax.axhspan(*nominal["ci95"], color="0.85", zorder=0)
        ax.axhline(nominal["rate"], color="0.4", lw=1, label="nominal")
        ax.errorbar(levels, rates, yerr=error_bars([p[1] for p in points]), marker="o", capsize=3, color="#4c72b0")
        ax.set_ylim(0, 1.05)
        ax.set_title(name, fontsize=9)
        ax.set_xlabel(conditions[0]["unit"], fontsize=8)
        ax.set_ylabel("success (95% CI)", fontsize=8)
    for ax in axes[len(names) :]:
        ax.axis("off")
    fig.suptitle(f"robustness · {title} · grey: nominal", fontsize=9)
    return _save(plt, fig, path)


def _save(plt, fig, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def success_against(xs: list, rates: list[dict], path: Path, xlabel: str, title: str, best: int | None = None) -> Path:
    """Success with its 95% interval at each x: training steps (numbers, joined by a line, for `kitbench select`)
    or settings (labels, for `kitbench sweep`); `best`: the index of the point drawn as the best."""
    numeric = all(isinstance(x, int | float) for x in xs)
    plt, fig, ax = _figure(max(6.0, 0.45 * len(xs)) if not numeric else 6.0, 3.8)
    at = list(xs) if numeric else list(range(len(xs)))
    ax.errorbar(
        at, [r["rate"] for r in rates], yerr=error_bars(rates), marker="o", capsize=3, color="#4c72b0",
        linestyle="-" if numeric else "none",
    )  # fmt: skip
    if best is not None:
        ax.plot([at[best]], [rates[best]["rate"]], marker="*", markersize=16, color="#dd8452", label="best")
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    if not numeric:
        ax.set_xticks(
            at, [str(x) for x in xs], rotation=45 if len(xs) > 3 else 0, ha="right" if len(xs) > 3 else "center"
        )
    if numeric:
        from matplotlib.ticker import MaxNLocator

        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_ylim(-0.03, 1.05)  # a point at 0% stays visible
    ax.set_xlabel(xlabel)
    ax.set_ylabel("success (95% Wilson CI)")
    ax.set_title(title, fontsize=9)
    path.parent.mkdir(parents=True, exist_ok=True)
    return _save(plt, fig, path)
