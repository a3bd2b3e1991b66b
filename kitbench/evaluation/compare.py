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

from dataclasses import dataclass
from pathlib import Path

from kitbench.config.declare import setting
from kitbench.errors import KitbenchError, check_choice
from kitbench.evaluation.compare_inputs import (
    Count,
    load_report,
    pair,
    paired_episodes,
    read_count,
    suite_differences,
)
from kitbench.evaluation.compare_table import Comparison, Row
from kitbench.evaluation.provenance import outcome_differences
from kitbench.evaluation.report import REPORT_VERSION, group_table
from kitbench.evaluation.significance import UNPAIRED_TESTS, check_alpha

# What the cameras rendered (None: the task's own size and framing). Fitted to each policy's training data, so
# two policies trained on different pictures are compared on the same episodes: a warning, not a refusal.
CAMERA_FIELDS = ("camera_size", "camera_view")


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
                paired = pair(subset, paired_outcome)
        rows.append(Row(section, name, higher_is_better, ca, cb, paired, unpaired_test=test))

    # success first: it is the headline
    add(
        "success",
        "success",
        True,
        read_count(a_path, "success", a["success"]),
        read_count(b_path, "success", b["success"]),
        lambda e: e["success"],
    )
    na, nb = rows[0].a, rows[0].b
    assert na is not None and nb is not None
    for metric in ("success_once", "success_at_end"):  # reports before version 2 have neither
        if metric in a or metric in b:
            ca = read_count(a_path, metric, a[metric]) if metric in a else None
            cb = read_count(b_path, metric, b[metric]) if metric in b else None
            add("success", metric, True, ca, cb, lambda e, metric=metric: e.get(metric))
    for name in dict.fromkeys([*a["criteria"], *b["criteria"]]):
        ca = read_count(a_path, f"criteria.{name}", a["criteria"][name]) if name in a["criteria"] else None
        cb = read_count(b_path, f"criteria.{name}", b["criteria"][name]) if name in b["criteria"] else None
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
            ca = None if ra is None else read_count(a_path, f"per_{name_key}.{gid}", ra)
            cb = None if rb is None else read_count(b_path, f"per_{name_key}.{gid}", rb)

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
        ca = None if ra is None else read_count(a_path, where, ra["success"])
        cb = None if rb is None else read_count(b_path, where, rb["success"])
        label = f"{key[0]} {key[1]:g} {(ra or rb or {}).get('unit', '')}".strip()
        pairs = None
        if ra is not None and rb is not None:
            pairs = paired_episodes(ra, rb)
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
    pairs = paired_episodes(a, b)
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
