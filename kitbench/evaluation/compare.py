"""Compare two evaluation reports (A, the baseline; B, the candidate): is B's success rate different from A's by
more than chance, on the same suite?

Every row (success, each success criterion, each failure category, each group of the task's `report_groups`)
gives both rates, the difference B - A, a 95% confidence interval of the difference and a two-sided p-value:

- Unpaired (always): Fisher's exact test on the 2x2 table of outcomes by report (`--test barnard`: Barnard's
  exact unconditional test, more powerful at small n and slower), and Newcombe's hybrid score interval
  ("square-and-add" of the two Wilson intervals, method 10 of Newcombe 1998, Stat. Med. 17:873).
- Paired (when both reports scored the same seeds and keep their per-episode results): McNemar's exact test,
  a binomial test of the discordant seeds (those where only one of A and B has the outcome), and Newcombe's
  square-and-add interval for paired data (Newcombe 1998, Stat. Med. 17:2635: the same construction, the two
  Wilson intervals combined with the correlation of the paired outcomes). A seed fixes an episode's initial
  state, so much of the variation between seeds is shared by A and B; the paired test removes it and is then
  the more powerful one. Only discordant seeds count: with k of them p is at least 2^(1-k), so fewer than 6
  can never be significant at 0.05, however lopsided (the unpaired column may then show a smaller p, from a
  test whose independence assumption the shared seeds break).

The headline is the success row under the paired test when there is one, else the unpaired test; it alone
decides the verdict (and `--fail-if-worse`). The other rows are diagnostics: many tests at once, not corrected
for multiple comparisons.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from kitbench.config.declare import setting
from kitbench.errors import KitbenchError, check_choice, one_line
from kitbench.evaluation.provenance import outcome_differences
from kitbench.evaluation.report import REPORT_VERSION, group_table, write_json
from kitbench.evaluation.significance import (
    UNPAIRED_TESTS,
    check_alpha,
    mcnemar_p,
    newcombe_interval,
    newcombe_paired_interval,
    unpaired_p,
)

COMPARE_VERSION = 1
TEST_NAMES = {"fisher": "Fisher's exact test", "barnard": "Barnard's exact test", "mcnemar": "McNemar's exact test"}
SHORT_NAMES = {"fisher": "Fisher", "barnard": "Barnard", "mcnemar": "McNemar"}
# What decides whether two reports measured the same thing (the suite's name, description and file do not).
SUITE_FIELDS = ("task", "seeds", "obs_mode", "control_mode", "reward_mode")
# Fields newer suites have, with the value an older report's suite had without them.
SUITE_DEFAULTS = {"settle_steps": 0, "perturbations": {}, "robot": None}
# What the cameras rendered (None: the task's own size and framing). Fitted to each policy's training data, so
# two policies trained on different pictures are compared on the same episodes: a warning, not a refusal.
CAMERA_FIELDS = ("camera_size", "camera_view")
BETTER, WORSE, NONE = "better", "worse", "none"


# ---------------------------------------------------------------------------------------------------------------
# reading reports


def _fail(path: Path, what: str) -> KitbenchError:
    return KitbenchError(f"{path} is not a kitbench report: {what}")


def load_report(path: str | Path) -> tuple[Path, dict]:
    """Read a `report.json` (or the report folder holding one) written by `kitbench eval`; returns the file's
    path and the report. Everything the comparison reads is checked here, so a wrong file fails in one line."""
    path = Path(path)
    if path.is_dir():
        path = path / "report.json"
    if not path.is_file():
        raise KitbenchError(f"no report at {path}")
    try:
        report = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise _fail(path, f"cannot read it as JSON ({one_line(exc, typed=False)})") from None
    if not isinstance(report, dict):
        raise _fail(path, "not a JSON object")
    for key in ("report_version", "suite", "success", "criteria", "failure_categories"):
        if key not in report:
            raise _fail(path, f"no {key!r}")
    for key in ("criteria", "failure_categories"):
        if not isinstance(report[key], dict):
            raise _fail(path, f"its {key!r} is not a table")
    suite = report["suite"]
    if not isinstance(suite, dict) or any(k not in suite for k in SUITE_FIELDS):
        raise _fail(path, f"its 'suite' lacks one of {', '.join(SUITE_FIELDS)}")
    if not isinstance(suite["seeds"], list) or not suite["seeds"]:
        raise _fail(path, "its suite has no seeds")
    n = _count(path, "success", report["success"]).episodes
    for name, entry in report["criteria"].items():
        _count(path, f"criteria.{name}", entry)
    for name, count in report["failure_categories"].items():
        if not isinstance(count, int) or not 0 <= count <= n:
            raise _fail(path, f"failure_categories.{name} is {count!r}, not a count of at most {n} episodes")
    groups = report.get("report_groups")
    if groups is not None:
        table = report.get(f"per_{groups[1]}") if isinstance(groups, list) and len(groups) == 2 else None
        if not isinstance(table, list) or any(not isinstance(r, dict) or not set(groups) <= set(r) for r in table):
            raise _fail(path, f"its report_groups {groups!r} have no per-group table")
        for row in table:
            _count(path, f"per_{groups[1]}.{row[groups[0]]}", row)
    episodes = report.get("per_episode")
    if episodes is not None:
        if not isinstance(episodes, list) or len(episodes) != n:
            raise _fail(path, f"per_episode does not hold its {n} episodes")
        for e in episodes:
            if not isinstance(e, dict) or any(k not in e for k in ("seed", "success", "criteria", "failure")):
                raise _fail(path, "a per_episode entry lacks seed, success, criteria or failure")
    return path, report


@dataclass(frozen=True)
class Count:
    """How many of `episodes` episodes had the outcome."""

    count: int
    episodes: int

    @property
    def rate(self) -> float:
        return self.count / self.episodes

    def to_dict(self) -> dict:
        return {"count": self.count, "episodes": self.episodes, "rate": self.rate}


def _count(path: Path, where: str, entry) -> Count:
    """A report's `rate()` entry ({count, episodes, rate, ci95}) as a Count."""
    if not isinstance(entry, dict) or "episodes" not in entry or ("count" not in entry and "rate" not in entry):
        raise _fail(path, f"{where} has no count and episodes")
    n, k = entry["episodes"], entry.get("count")
    if k is None and isinstance(n, int) and isinstance(entry["rate"], float | int):
        # the count is exact; a hand-made report with only a rate gets the count the rate stands for
        k = round(entry["rate"] * n)
    if not isinstance(n, int) or not isinstance(k, int) or n < 1 or not 0 <= k <= n:
        raise _fail(path, f"{where} counts {k!r} of {n!r} episodes")
    return Count(k, n)


# ---------------------------------------------------------------------------------------------------------------
# the comparison


@dataclass(frozen=True)
class Paired:
    """Outcomes on the seeds both reports scored: only A, only B, both, neither had the outcome."""

    a_only: int
    b_only: int
    both: int
    neither: int

    def to_dict(self) -> dict:
        return {"a_only": self.a_only, "b_only": self.b_only, "both": self.both, "neither": self.neither}


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


def _seeds_text(seeds: list) -> str:
    if len(seeds) > 1 and seeds == list(range(seeds[0], seeds[0] + len(seeds))):
        return f"{len(seeds)} seeds {seeds[0]}…{seeds[-1]}"
    shown = ", ".join(map(str, seeds[:4])) + (", …" if len(seeds) > 4 else "")
    return f"{len(seeds)} seed{'s' if len(seeds) != 1 else ''} [{shown}]"


def suite_differences(a: dict, b: dict) -> list[str]:
    """How two reports' suites differ in what decides the numbers, one phrase each, naming both values."""
    sa, sb = a["suite"], b["suite"]
    found = []
    for key in SUITE_FIELDS:
        va, vb = sa[key], sb[key]
        if key == "seeds":
            # the same episodes in another order are the same suite
            if sorted(va) != sorted(vb):
                ta, tb = _seeds_text(va), _seeds_text(vb)
                if ta == tb:  # same count and ends: name the first seed that is not in both
                    only = sorted(set(va) ^ set(vb))[0]
                    ta, tb = f"{ta} ({'with' if only in va else 'without'} {only})", tb
                found.append(f"seeds: A has {ta}, B has {tb}")
        elif va != vb:
            found.append(f"{key}: A {va!r}, B {vb!r}")
    for key, default in SUITE_DEFAULTS.items():
        va, vb = sa.get(key, default), sb.get(key, default)
        if va != vb:
            found.append(f"{key}: A {va!r}, B {vb!r}")
    return found


def _paired_episodes(a: dict, b: dict) -> list[tuple[dict, dict]] | None:
    """A's and B's per-episode results seed by seed, when both reports have them for the same seeds."""
    ea, eb = a.get("per_episode"), b.get("per_episode")
    if ea is None or eb is None:
        return None
    by_seed_a, by_seed_b = {e["seed"]: e for e in ea}, {e["seed"]: e for e in eb}
    if len(by_seed_a) != len(ea) or set(by_seed_a) != set(by_seed_b) or len(by_seed_b) != len(eb):
        return None
    return [(by_seed_a[s], by_seed_b[s]) for s in sorted(by_seed_a)]


def _pair(pairs: list[tuple[dict, dict]], outcome) -> Paired:
    counts = {(True, True): 0, (True, False): 0, (False, True): 0, (False, False): 0}
    for ea, eb in pairs:
        counts[(bool(outcome(ea)), bool(outcome(eb)))] += 1
    return Paired(
        a_only=counts[(True, False)],
        b_only=counts[(False, True)],
        both=counts[(True, True)],
        neither=counts[(False, False)],
    )


def _groups(report: dict) -> tuple[str, str, dict] | None:
    """The report's per-group table (id key, name key, {group id: row})."""
    table = group_table(report)
    if table is None:
        return None
    id_key, name_key, rows = table
    return id_key, name_key, {row[id_key]: row for row in rows}


def _rows(a: dict, b: dict, a_path: Path, b_path: Path, pairs, test: str) -> list[Row]:
    rows = []

    def add(section, name, higher_is_better, ca, cb, paired_outcome=None, paired_subset=None, own_pairs=None):
        paired = None
        chosen = pairs if own_pairs is None else own_pairs
        if chosen is not None and paired_outcome is not None and ca is not None and cb is not None:
            subset = chosen if paired_subset is None else [p for p in chosen if paired_subset(*p)]
            if subset:
                paired = _pair(subset, paired_outcome)
        rows.append(Row(section, name, higher_is_better, ca, cb, paired, unpaired_test=test))

    # success first: it is the headline
    add(
        "success",
        "success",
        True,
        _count(a_path, "success", a["success"]),
        _count(b_path, "success", b["success"]),
        lambda e: e["success"],
    )
    na, nb = rows[0].a, rows[0].b
    assert na is not None and nb is not None
    for metric in ("success_once", "success_at_end"):  # reports before version 2 have neither
        if metric in a or metric in b:
            ca = _count(a_path, metric, a[metric]) if metric in a else None
            cb = _count(b_path, metric, b[metric]) if metric in b else None
            add("success", metric, True, ca, cb, lambda e, metric=metric: e.get(metric))
    for name in dict.fromkeys([*a["criteria"], *b["criteria"]]):
        ca = _count(a_path, f"criteria.{name}", a["criteria"][name]) if name in a["criteria"] else None
        cb = _count(b_path, f"criteria.{name}", b["criteria"][name]) if name in b["criteria"] else None
        add("criterion", name, True, ca, cb, lambda e, name=name: e["criteria"].get(name))
    for name in dict.fromkeys([*a["failure_categories"], *b["failure_categories"]]):
        fa, fb = a["failure_categories"].get(name), b["failure_categories"].get(name)
        ca = None if fa is None else Count(fa, na.episodes)
        cb = None if fb is None else Count(fb, nb.episodes)
        add("failure", name, False, ca, cb, lambda e, name=name: e["failure"] == name)
    ga, gb = _groups(a), _groups(b)
    if ga is not None or gb is not None:
        source = ga if ga is not None else gb
        assert source is not None
        id_key, name_key = source[0], source[1]
        rows_a = ga[2] if ga is not None and ga[:2] == (id_key, name_key) else {}
        rows_b = gb[2] if gb is not None and gb[:2] == (id_key, name_key) else {}
        for gid in sorted(set(rows_a) | set(rows_b)):
            ra, rb = rows_a.get(gid), rows_b.get(gid)
            label = f"{gid} ({rows_a[gid][name_key] if ra is not None else rows_b[gid][name_key]})"
            ca = None if ra is None else _count(a_path, f"per_{name_key}.{gid}", ra)
            cb = None if rb is None else _count(b_path, f"per_{name_key}.{gid}", rb)

            # a seed's group is fixed by the seed (its episode config), so the pairs of a group are the seeds
            # that are in it in both reports
            def in_group(ea, eb, gid=gid):
                return ea.get("config", {}).get(id_key) == gid and eb.get("config", {}).get(id_key) == gid

            add(name_key, label, True, ca, cb, lambda e: e["success"], in_group)
    _robustness_rows(a, b, a_path, b_path, add)
    for row in rows:
        row.compute()
    return rows


def _robustness_rows(a: dict, b: dict, a_path: Path, b_path: Path, add) -> None:
    """One row per perturbation and level either report scored, paired on the seeds both ran under it."""
    ca_all = {(c["perturbation"], c["level"]): c for c in a.get("robustness", [])}
    cb_all = {(c["perturbation"], c["level"]): c for c in b.get("robustness", [])}
    for key in dict.fromkeys([*ca_all, *cb_all]):
        ra, rb = ca_all.get(key), cb_all.get(key)
        where = f"robustness.{key[0]}={key[1]:g}"
        ca = None if ra is None else _count(a_path, where, ra["success"])
        cb = None if rb is None else _count(b_path, where, rb["success"])
        label = f"{key[0]} {key[1]:g} {(ra or rb or {}).get('unit', '')}".strip()
        pairs = None
        if ra is not None and rb is not None:
            pairs = _paired_episodes(ra, rb)
        add("perturbation", label, True, ca, cb, lambda e: e["success"], None, pairs)


@dataclass
class CompareSettings:
    # The baseline: a report.json (or its report folder).
    a: Path = setting(positional=True, metavar="A")
    # The candidate: a report.json (or its report folder).
    b: Path = setting(positional=True, metavar="B")
    # The significance level, between 0 and 1.
    alpha: str = setting("0.05")
    # The unpaired test: fisher or barnard (more powerful, slower); when both reports scored the same seeds the
    # headline is McNemar's paired test.
    test: str = setting("fisher")
    # Also write the comparison to this JSON file.
    json: Path | None = setting(None)
    # Compare reports whose task, seeds or modes differ (with a warning) instead of refusing.
    allow_different_suites: bool = setting(False)
    # Exit 1 when B's success rate is significantly lower than A's (default: exit 0 whatever the verdict).
    fail_if_worse: bool = setting(False)


def compare_reports(
    a_path: str | Path,
    b_path: str | Path,
    alpha: float | str = 0.05,
    test: str = "fisher",
    allow_different_suites: bool = False,
) -> Comparison:
    """Compare report B with report A (paths to report.json or their folders). Reports of different suites
    (task, seeds, modes) are refused unless `allow_different_suites`; a KitbenchError says what differs."""
    alpha = check_alpha(alpha)
    check_choice("test", test, UNPAIRED_TESTS)
    pa, a = load_report(a_path)
    pb, b = load_report(b_path)
    differences = suite_differences(a, b)
    warnings = []
    if differences:
        if not allow_different_suites:
            raise KitbenchError(
                "the reports are of different suites ("
                + "; ".join(differences)
                + "); pass --allow-different-suites to compare them anyway"
            )
        warnings.append(
            "comparing different suites (" + "; ".join(differences) + "): a difference may come from the suites"
        )
    warnings += [
        f"{key} differs: A {a.get(key)!r}, B {b.get(key)!r}"
        for key in ("report_version", "kitbench_version")
        if a.get(key) != b.get(key)
    ]
    warnings += [
        f"the cameras differ: {key} A {a['suite'].get(key)!r}, B {b['suite'].get(key)!r}"
        for key in CAMERA_FIELDS
        if a["suite"].get(key) != b["suite"].get(key)
    ]
    for path, r in ((pa, a), (pb, b)):
        if isinstance(r["report_version"], int) and r["report_version"] > REPORT_VERSION:
            warnings.append(f"{path} has report_version {r['report_version']}, newer than this kitbench's")
    pairs = _paired_episodes(a, b)
    rows = _rows(a, b, pa, pb, pairs, test)
    return Comparison(
        a_path=pa,
        b_path=pb,
        a=a,
        b=b,
        alpha=alpha,
        unpaired_test=test,
        paired=rows[0].paired is not None,
        same_suite=not differences,
        differences=differences,
        rows=rows,
        warnings=warnings,
        provenance_differences=outcome_differences(a.get("provenance"), b.get("provenance")),
    )
