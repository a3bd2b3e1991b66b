"""A comparison's result: one row per metric with its paired and unpaired tests, and the readable table, the
verdict and the JSON made from the rows."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from kitbench.errors import KitbenchError
from kitbench.evaluation.compare_inputs import Count, Paired
from kitbench.evaluation.report import write_json
from kitbench.evaluation.significance import mcnemar_p, newcombe_interval, newcombe_paired_interval, unpaired_p

COMPARE_VERSION = 1
TEST_NAMES = {"fisher": "Fisher's exact test", "barnard": "Barnard's exact test", "mcnemar": "McNemar's exact test"}
SHORT_NAMES = {"fisher": "Fisher", "barnard": "Barnard", "mcnemar": "McNemar"}
BETTER, WORSE, NONE = "better", "worse", "none"


@dataclass
class Row:
    """One metric of both reports. `higher_is_better` is False for failure categories."""

    section: str  # success, criterion, failure or the group name (e.g. the task's per-group key)
    name: str
    higher_is_better: bool
    a: Count | None  # None: the report has no such metric (possible only across different suites)
    b: Count | None
    paired: Paired | None = None
    unpaired_test: str = "fisher"
    difference: float | None = None  # rate(B) - rate(A)
    unpaired_p: float | None = None
    unpaired_ci: tuple[float, float] | None = None
    paired_p: float | None = None
    paired_ci: tuple[float, float] | None = None

    def compute(self) -> None:
        if self.a is None or self.b is None:
            return
        a, b = self.a, self.b
        self.difference = b.rate - a.rate
        self.unpaired_p = unpaired_p(a.count, a.episodes, b.count, b.episodes, self.unpaired_test)
        self.unpaired_ci = newcombe_interval(a.count, a.episodes, b.count, b.episodes)
        if self.paired is not None:
            q = self.paired
            self.paired_p = mcnemar_p(q.a_only, q.b_only)
            self.paired_ci = newcombe_paired_interval(q.a_only, q.b_only, q.both, q.neither)

    @property
    def label(self) -> str:
        return self.name if self.section == "success" else f"{self.section} {self.name}"

    @property
    def p(self) -> float | None:
        """The headline test's p-value for this row: paired where there is a pairing."""
        return self.paired_p if self.paired is not None else self.unpaired_p

    @property
    def ci(self) -> tuple[float, float] | None:
        return self.paired_ci if self.paired is not None else self.unpaired_ci

    def verdict(self, alpha: float) -> str:
        if self.p is None or self.difference is None or self.p >= alpha or self.difference == 0:
            return NONE
        return BETTER if (self.difference > 0) == self.higher_is_better else WORSE

    def to_dict(self, alpha: float) -> dict:
        return {
            "section": self.section,
            "name": self.name,
            "higher_is_better": self.higher_is_better,
            "a": None if self.a is None else self.a.to_dict(),
            "b": None if self.b is None else self.b.to_dict(),
            "difference": self.difference,
            "unpaired": {"test": self.unpaired_test, "p": self.unpaired_p, "ci95": _list(self.unpaired_ci)},
            "paired": None
            if self.paired is None
            else {"test": "mcnemar", **self.paired.to_dict(), "p": self.paired_p, "ci95": _list(self.paired_ci)},
            "p": self.p,
            "ci95": _list(self.ci),
            "verdict": self.verdict(alpha),
        }


def _list(ci: tuple[float, float] | None) -> list[float] | None:
    return None if ci is None else list(ci)


def _pct(x: float) -> str:
    return f"{x:.1%}"


def format_p(p: float | None, alpha: float | None = None) -> str:
    if p is None:
        return "–"
    text = f"{p:.3g}"
    if alpha is not None and float(text) == alpha and p != alpha:
        text = f"{p:.6g}"  # never print "p = 0.05 < alpha 0.05"
    return text


@dataclass
class Comparison:
    a_path: Path
    b_path: Path
    a: dict  # the reports
    b: dict
    alpha: float
    unpaired_test: str
    paired: bool  # the headline is McNemar's paired test
    same_suite: bool
    differences: list[str]  # how the suites differ (empty when they do not)
    rows: list[Row]
    warnings: list[str] = field(default_factory=list)
    # how the reports' provenance differs where that can change an outcome (execution settings, versions, driver)
    provenance_differences: list[str] = field(default_factory=list)

    @property
    def headline(self) -> Row:
        return self.rows[0]

    @property
    def headline_test(self) -> str:
        return "mcnemar" if self.paired else self.unpaired_test

    @property
    def verdict(self) -> str:
        return self.headline.verdict(self.alpha)

    def verdict_line(self) -> str:
        row, alpha = self.headline, self.alpha
        assert row.a is not None and row.b is not None and row.p is not None  # success is in every report
        p = format_p(row.p, alpha)
        change = f"success {_pct(row.a.rate)} -> {_pct(row.b.rate)}, {SHORT_NAMES[self.headline_test]} p = {p}"
        if self.verdict == NONE:
            return f"verdict: no significant difference ({change} >= alpha {alpha:g})"
        return f"verdict: B is {self.verdict} than A ({change} < alpha {alpha:g})"

    def _headline_lines(self) -> list[str]:
        n = self.headline.a.episodes if self.headline.a else 0
        unpaired = TEST_NAMES[self.unpaired_test]
        if self.paired:
            return [
                (
                    f"headline: success by McNemar's exact test, paired on the {n} seeds both reports scored "
                    f"({unpaired}, unpaired, beside it)"
                ),
                "95% CI of B−A: Newcombe's paired score interval",
            ]
        seeds_differ = sorted(self.a["suite"]["seeds"]) != sorted(self.b["suite"]["seeds"])
        why = "the reports scored different seeds" if seeds_differ else "a report has no per-episode results"
        return [
            f"headline: success by {unpaired}, unpaired ({why})",
            "95% CI of B−A: Newcombe's hybrid score interval",
        ]

    def lines(self) -> list[str]:
        """The readable comparison; the last line is the verdict."""
        a, b = self.a, self.b
        suite = a["suite"]
        out = [
            f"A: {a.get('policy', '?')} · {self.a_path}",
            f"B: {b.get('policy', '?')} · {self.b_path}",
        ]
        if self.same_suite:
            out.append(
                f"suite: {suite.get('name', '?')} · {suite['task']} · {len(suite['seeds'])} seeds · obs "
                f"{suite['obs_mode']} · control {suite['control_mode']} · reward {suite['reward_mode']}"
            )
        else:
            out.append("suites differ: " + "; ".join(self.differences))
        out += self._headline_lines()
        p_cols = (["p McNemar"] if self.paired else []) + [f"p {SHORT_NAMES[self.unpaired_test]}"]
        header = ["metric", "A", "B", "B−A", "95% CI", *p_cols, "verdict"]
        table = [header]
        for row in self.rows:
            # a failure category that neither report has says nothing (the JSON keeps it)
            if row.section == "failure" and all(c is None or c.count == 0 for c in (row.a, row.b)):
                continue
            cells = [
                row.label,
                _cell(row.a),
                _cell(row.b),
                "–" if row.difference is None else f"{100 * row.difference:+.1f} pp",
                "–" if row.ci is None else f"[{100 * row.ci[0]:+.1f}, {100 * row.ci[1]:+.1f}]",
            ]
            if self.paired:
                cells.append(format_p(row.paired_p))
            cells.append(format_p(row.unpaired_p))
            verdict = row.verdict(self.alpha)
            cells.append("" if verdict == NONE else verdict)
            table.append(cells)
        widths = [max(len(r[i]) for r in table) for i in range(len(header))]
        out.append("")
        for cells in table:
            # text left, numbers right
            out.append(
                "  ".join(
                    c.ljust(w) if i in (0, len(header) - 1) else c.rjust(w)
                    for i, (c, w) in enumerate(zip(cells, widths, strict=True))
                ).rstrip()
            )
        if self.provenance_differences:
            out += ["", "the reports ran differently in what can change an outcome (report.json's provenance):"]
            out += [f"  {line}" for line in self.provenance_differences]
        out += [
            "",
            f"verdict column: p < alpha {self.alpha:g} by the headline test; fewer failures are better",
            "only the success row decides the verdict: the others are diagnostics, uncorrected for multiple tests",
            self.verdict_line(),
        ]
        return out

    def to_dict(self) -> dict:
        def side(path: Path, r: dict) -> dict:
            return {
                "path": str(path),
                "policy": r.get("policy"),
                "suite": r["suite"],
                "report_version": r.get("report_version"),
                "kitbench_version": r.get("kitbench_version"),
            }

        return {
            "compare_version": COMPARE_VERSION,
            "a": side(self.a_path, self.a),
            "b": side(self.b_path, self.b),
            "same_suite": self.same_suite,
            "suite_differences": self.differences,
            "alpha": self.alpha,
            "paired": self.paired,
            "headline_test": self.headline_test,
            "unpaired_test": self.unpaired_test,
            "ci_method": "newcombe-paired" if self.paired else "newcombe-hybrid-score",
            "warnings": self.warnings,
            "provenance_differences": self.provenance_differences,
            "verdict": {
                "outcome": self.verdict,
                "metric": "success",
                "p": self.headline.p,
                "difference": self.headline.difference,
                "ci95": _list(self.headline.ci),
                "line": self.verdict_line(),
            },
            "rows": [row.to_dict(self.alpha) for row in self.rows],
        }

    def write_json(self, path: str | Path) -> None:
        path = Path(path)
        try:
            write_json(self.to_dict(), path)
        except OSError as exc:
            raise KitbenchError(f"cannot write {path}: {exc.strerror or exc}") from None


def _cell(c: Count | None) -> str:
    return "–" if c is None else f"{_pct(c.rate)} ({c.count}/{c.episodes})"
