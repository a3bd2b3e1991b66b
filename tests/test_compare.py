"""`kitbench compare`: two reports, their difference, its interval and p-value, and the verdict a CI job gates on.

Reports here are synthetic, made by the report builder itself from chosen episode outcomes (no simulation), so
they have exactly the shape `kitbench eval` writes; one test checks that shape against two real evaluations.
The expected p-values are computed here from their definitions with exact fractions, not with scipy, and the
intervals are checked against Newcombe's published values.
"""

from __future__ import annotations

import json
from fractions import Fraction
from math import comb, sqrt
from pathlib import Path

import pytest

from kitbench import cli
from kitbench.errors import KitbenchError
from kitbench.evaluation.compare import compare_reports
from kitbench.evaluation.config import EvalConfig
from kitbench.evaluation.episode import EpisodeResult
from kitbench.evaluation.report import build_report, markdown
from kitbench.evaluation.runner import run_eval
from kitbench.evaluation.significance import newcombe_interval, newcombe_paired_interval
from kitbench.evaluation.suite import Suite, load_suite
from kitbench.registration import task_entry

ROOT = Path(__file__).resolve().parents[1]
LIFT, KITS = "LiftPegUpright-v1", "AssemblingKits-v1"
SEEDS = tuple(range(1_000_000, 1_000_020))


# ----------------------------------------------------------------------------------------------------------------
# synthetic reports


def make_report(
    task: str,
    successes: list[bool],
    seeds: tuple[int, ...] | None = None,
    failures: list[str] | None = None,
    groups: list[int] | None = None,
    policy: str = "policy",
    **modes,
) -> dict:
    """A report.json-shaped dict for episodes with these outcomes (seed k gets successes[k]), built by
    `build_report` as `kitbench eval` builds it. A failure's category is `failures` in turn (default: the
    task's first) and its criteria are all false; `groups` gives each episode's group id (for tasks with
    `report_groups`)."""
    env_class = task_entry(task).env_class
    seeds = seeds or SEEDS[: len(successes)]
    failures = failures or [env_class.failure_categories[0]]
    results, k = [], 0
    for i, (seed, ok) in enumerate(zip(seeds, successes, strict=True)):
        config = {}
        if env_class.report_groups is not None:
            id_key, name_key = env_class.report_groups
            gid = groups[i] if groups else 0
            config = {id_key: gid, name_key: f"shape{gid}"}
        failure = None if ok else failures[k % len(failures)]
        k += not ok
        results.append(
            EpisodeResult(
                seed=seed,
                success=ok,
                length=40 if ok else 50,
                steps_to_success=40 if ok else None,
                episode_return=1.0 if ok else 0.0,
                criteria=dict.fromkeys(env_class.success_criteria, ok),
                failure=failure,
                config=config,
                final={"success": ok},
                success_once=ok,
                success_at_end=ok,
            )
        )
    suite = Suite(name="synthetic", task=task, seeds=tuple(seeds), **modes)
    report = build_report(suite, policy, results, 0.05)
    return json.loads(json.dumps(report))  # what a reader of report.json gets (tuples are lists, ...)


def write(tmp_path: Path, name: str, report: dict) -> str:
    folder = tmp_path / name
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "report.json").write_text(json.dumps(report))
    return str(folder / "report.json")


def pair(tmp_path: Path, a: dict, b: dict) -> tuple[str, str]:
    return write(tmp_path, "a", a), write(tmp_path, "b", b)


def outcomes(k: int, n: int) -> list[bool]:
    return [True] * k + [False] * (n - k)


# ----------------------------------------------------------------------------------------------------------------
# the tests' own statistics: from the definitions, with exact arithmetic


def fisher_p(a: int, n1: int, b: int, n2: int) -> float:
    """Two-sided Fisher: the probability, given both margins, of a table no more likely than the observed one."""
    total, k = n1 + n2, a + b

    def prob(x: int) -> Fraction:  # hypergeometric: x of the k successes fall in the first sample
        return Fraction(comb(n1, x) * comb(n2, k - x), comb(total, k))

    observed = prob(a)
    return float(sum(prob(x) for x in range(max(0, k - n2), min(n1, k) + 1) if prob(x) <= observed))


def mcnemar_p(a_only: int, b_only: int) -> float:
    """Exact McNemar: two-sided binomial(a_only + b_only, 1/2) test of the discordant pairs."""
    n = a_only + b_only
    tail = sum(Fraction(comb(n, x), 2**n) for x in range(min(a_only, b_only) + 1))
    return float(min(Fraction(1), 2 * tail))


def barnard_p(a: int, n1: int, b: int, n2: int, grid: int = 2000) -> float:
    """Two-sided Barnard (pooled Wald statistic): the largest, over the common success probability, chance of
    a table at least as extreme as the observed one."""

    def stat(x1: int, x2: int) -> float:
        pooled = (x1 + x2) / (n1 + n2)
        var = pooled * (1 - pooled) * (1 / n1 + 1 / n2)
        return 0.0 if var == 0 else (x2 / n2 - x1 / n1) / sqrt(var)

    observed = abs(stat(a, b))
    extreme = [(x1, x2) for x1 in range(n1 + 1) for x2 in range(n2 + 1) if abs(stat(x1, x2)) >= observed - 1e-12]
    best = 0.0
    for i in range(1, grid):
        pi = i / grid
        best = max(
            best,
            sum(
                comb(n1, x1) * pi**x1 * (1 - pi) ** (n1 - x1) * comb(n2, x2) * pi**x2 * (1 - pi) ** (n2 - x2)
                for x1, x2 in extreme
            ),
        )
    return best


# ----------------------------------------------------------------------------------------------------------------
# intervals


def test_newcombe_interval_matches_the_published_values():
    # Newcombe (1998), Stat. Med. 17:873, Table II, method 10 (differences p1 - p2, here B - A)
    for (a, n1, b, n2), (lo, hi) in {
        (48, 80, 56, 70): (0.0524, 0.3339),
        (3, 10, 9, 10): (0.1705, 0.8090),
        (0, 20, 0, 10): (-0.1611, 0.2775),
        (0, 10, 0, 10): (-0.2775, 0.2775),
        (0, 20, 10, 10): (0.6791, 1.0),
        (0, 10, 10, 10): (0.6075, 1.0),
    }.items():
        assert newcombe_interval(a, n1, b, n2) == pytest.approx((lo, hi), abs=5e-5)


def test_newcombe_paired_interval_matches_a_published_value():
    # Fagerland, Lydersen & Laake, "Statistical Analysis of Contingency Tables" (2017), ch. 8: complete response
    # before (B here) and after (A) consolidation therapy, Cavo et al. 2012: 59 both, 6 only before, 16 only after
    # -> -0.0621 (95% CI -0.1186 to -0.0046)
    assert newcombe_paired_interval(a_only=16, b_only=6, both=59, neither=80) == pytest.approx(
        (-0.1186, -0.0046), abs=5e-5
    )
    # no correlation to use when a margin is empty: the same as the unpaired interval
    assert newcombe_paired_interval(a_only=0, b_only=6, both=0, neither=0) == pytest.approx(
        newcombe_interval(0, 6, 6, 6)
    )


# ----------------------------------------------------------------------------------------------------------------
# p-values and differences


def test_different_seeds_use_fishers_test(tmp_path):
    a = make_report(LIFT, outcomes(3, 10), seeds=SEEDS[:10])
    b = make_report(LIFT, outcomes(9, 10), seeds=SEEDS[:10])
    # same suite, but one report without per-episode results cannot be paired
    del b["per_episode"]
    c = compare_reports(*pair(tmp_path, a, b))
    assert not c.paired and c.headline_test == "fisher"
    row = c.headline
    assert row.difference == pytest.approx(0.6)
    assert row.p == pytest.approx(fisher_p(3, 10, 9, 10), rel=1e-9)
    assert row.p == pytest.approx(0.01977, abs=1e-5)  # = 2 * 0.00988 (the table and its mirror image)
    assert row.ci == pytest.approx(newcombe_interval(3, 10, 9, 10))
    assert c.verdict == "better"
    assert c.verdict_line() == "verdict: B is better than A (success 30.0% -> 90.0%, Fisher p = 0.0198 < alpha 0.05)"
    assert any("a report has no per-episode results" in line for line in c.lines())


def test_criteria_and_failure_categories_are_compared_too(tmp_path):
    a = make_report(LIFT, outcomes(4, 12), failures=["never_grasped", "dropped"])
    b = make_report(LIFT, outcomes(10, 12), failures=["dropped"])
    c = compare_reports(*pair(tmp_path, a, b))
    rows = {(r.section, r.name): r for r in c.rows}
    assert set(rows) >= {("criterion", "upright"), ("criterion", "at_height"), ("failure", "never_grasped")}
    # unpaired p-values from the summary counts
    assert rows["criterion", "upright"].unpaired_p == pytest.approx(fisher_p(4, 12, 10, 12), rel=1e-9)
    never = rows["failure", "never_grasped"]  # A: 4 of its 8 failures, B: none
    assert (never.a.count, never.b.count) == (4, 0)
    assert never.unpaired_p == pytest.approx(fisher_p(4, 12, 0, 12), rel=1e-9)
    # paired on the same seeds: A's failures 4..11 never grasped or dropped in turn, B's 10, 11 dropped
    assert never.paired.a_only == 4 and never.paired.b_only == 0
    assert never.p == pytest.approx(mcnemar_p(4, 0))
    dropped = rows["failure", "dropped"]
    assert (dropped.a.count, dropped.b.count) == (4, 2) and dropped.difference < 0
    # fewer failures are better
    assert never.higher_is_better is False and never.verdict(0.2) == "better"
    # a report with rates only (no counts, no episodes) is compared on the counts the rates stand for
    for report in (a, b):
        del report["per_episode"]
        for entry in report["criteria"].values():
            del entry["count"]
    upright = next(r for r in compare_reports(*pair(tmp_path, a, b)).rows if r.name == "upright")
    assert (upright.name, upright.a.count, upright.b.count, upright.paired) == ("upright", 4, 10, None)
    assert upright.p == pytest.approx(fisher_p(4, 12, 10, 12), rel=1e-9)


def test_same_seeds_use_mcnemars_paired_test(tmp_path):
    # 20 seeds: both succeed on 10, only A on 1, only B on 7, neither on 2
    a = make_report(LIFT, [True] * 10 + [True] + [False] * 7 + [False] * 2)
    b = make_report(LIFT, [True] * 10 + [False] + [True] * 7 + [False] * 2)
    c = compare_reports(*pair(tmp_path, a, b))
    assert c.paired and c.headline_test == "mcnemar"
    row = c.headline
    assert (row.paired.a_only, row.paired.b_only, row.paired.both, row.paired.neither) == (1, 7, 10, 2)
    assert row.difference == pytest.approx((7 - 1) / 20)
    assert row.paired_p == pytest.approx(mcnemar_p(1, 7), rel=1e-12)
    assert row.paired_p == pytest.approx(18 / 256)  # 2 * (1 + 8) / 2^8
    assert row.unpaired_p == pytest.approx(fisher_p(11, 20, 17, 20), rel=1e-9)
    assert row.p == row.paired_p and row.ci == pytest.approx(newcombe_paired_interval(1, 7, 10, 2))
    lines = c.lines()
    assert any(line.startswith("headline: success by McNemar's exact test, paired on the 20 seeds") for line in lines)
    assert lines[-1] == "verdict: no significant difference (success 55.0% -> 85.0%, McNemar p = 0.0703 >= alpha 0.05)"
    # at alpha 0.1 the same numbers are significant
    assert compare_reports(*pair(tmp_path, a, b), alpha=0.1).verdict == "better"


def test_seeds_in_another_order_are_the_same_suite_and_still_paired(tmp_path):
    a = make_report(LIFT, outcomes(2, 6))
    b = make_report(LIFT, outcomes(5, 6)[::-1], seeds=SEEDS[:6][::-1])  # B lists its seeds backwards
    c = compare_reports(*pair(tmp_path, a, b))
    assert c.same_suite and c.paired
    assert (c.headline.paired.a_only, c.headline.paired.b_only) == (0, 3)


def test_barnards_test_on_request(tmp_path):
    a = make_report(LIFT, outcomes(2, 8), seeds=SEEDS[:8])
    b = make_report(LIFT, outcomes(7, 8), seeds=SEEDS[10:18])
    c = compare_reports(*pair(tmp_path, a, b), test="barnard", allow_different_suites=True)
    assert c.headline_test == "barnard"
    assert c.headline.p == pytest.approx(barnard_p(2, 8, 7, 8), abs=2e-4)
    # more powerful than Fisher's on this table
    assert c.headline.p < fisher_p(2, 8, 7, 8)
    assert "verdict: B is better than A (success 25.0% -> 87.5%, Barnard p = " in c.verdict_line()


def test_groups_are_compared_row_by_row(tmp_path):
    groups = [3] * 8 + [11] * 8
    # B gains on shape 3 what it loses on shape 11
    a = make_report(KITS, outcomes(2, 8) + outcomes(8, 8), groups=groups)
    b = make_report(KITS, outcomes(8, 8) + outcomes(2, 8), groups=groups)
    c = compare_reports(*pair(tmp_path, a, b))
    rows = [r for r in c.rows if r.section == "shape"]
    assert [r.name for r in rows] == ["3 (shape3)", "11 (shape11)"]  # by id
    three, eleven = rows
    assert (three.a.count, three.b.count, eleven.a.count, eleven.b.count) == (2, 8, 8, 2)
    assert three.unpaired_p == pytest.approx(fisher_p(2, 8, 8, 8), rel=1e-9)
    assert (three.paired.a_only, three.paired.b_only) == (0, 6) and three.verdict(0.05) == "better"
    assert eleven.paired_p == pytest.approx(mcnemar_p(6, 0)) and eleven.verdict(0.05) == "worse"
    # the overall success rate is the same (10 of 16): no difference on the headline
    assert c.headline.difference == 0 and c.verdict == "none"
    table = "\n".join(c.lines())
    assert "shape 3 (shape3)" in table and "shape 11 (shape11)" in table


# ----------------------------------------------------------------------------------------------------------------
# suites


def test_different_suites_are_refused_naming_the_difference(tmp_path):
    a = make_report(LIFT, outcomes(3, 6))
    b = make_report(LIFT, outcomes(3, 6), seeds=SEEDS[6:12])
    with pytest.raises(KitbenchError) as info:
        compare_reports(*pair(tmp_path, a, b))
    assert str(info.value) == (
        "the reports are of different suites (seeds: A has 6 seeds 1000000…1000005, B has 6 seeds "
        "1000006…1000011); pass --allow-different-suites to compare them anyway"
    )
    c = make_report(LIFT, outcomes(3, 6), control_mode="pd_ee_delta_pose")
    with pytest.raises(KitbenchError, match=r"control_mode: A 'pd_joint_pos', B 'pd_ee_delta_pose'"):
        compare_reports(*pair(tmp_path, a, c))
    d = make_report(KITS, outcomes(3, 6))
    with pytest.raises(KitbenchError, match=r"task: A 'LiftPegUpright-v1', B 'AssemblingKits-v1'"):
        compare_reports(*pair(tmp_path, a, d))


def test_different_suites_on_request_warn(tmp_path, capsys):
    a = make_report(LIFT, outcomes(3, 6))
    b = make_report(LIFT, outcomes(3, 6), seeds=SEEDS[6:12])
    assert cli.main(["compare", *pair(tmp_path, a, b), "--allow-different-suites"]) == 0
    out, err = capsys.readouterr()
    assert err == (
        "kitbench compare: warning: comparing different suites (seeds: A has 6 seeds 1000000…1000005, B has 6 "
        "seeds 1000006…1000011): a difference may come from the suites\n"
    )
    assert "headline: success by Fisher's exact test, unpaired (the reports scored different seeds)" in out
    assert out.splitlines()[-1].startswith("verdict: no significant difference")


def test_policies_scored_from_other_cameras_compare_paired_with_a_warning(tmp_path, capsys):
    # each policy is scored from the pictures it was trained on: same episodes, other cameras
    a = make_report(LIFT, outcomes(3, 6), obs_mode="rgb")
    b = make_report(LIFT, outcomes(3, 6), obs_mode="rgb", camera_size="96", camera_view="peg")
    assert (b["suite"]["camera_size"], b["suite"]["camera_view"]) == ("96x96", "peg")
    assert a["suite"]["camera_size"] is a["suite"]["camera_view"] is None
    assert cli.main(["compare", *pair(tmp_path, a, b)]) == 0
    out, err = capsys.readouterr()
    assert err == (
        "kitbench compare: warning: the cameras differ: camera_size A None, B '96x96'\n"
        "kitbench compare: warning: the cameras differ: camera_view A None, B 'peg'\n"
    )
    assert "McNemar" in out
    assert "obs `rgb` (cameras `96x96`, view `peg`), control" in markdown(b)
    assert "obs `rgb`, control" in markdown(a)


def test_other_versions_are_a_warning_not_an_error(tmp_path, capsys):
    a = make_report(LIFT, outcomes(3, 6))
    b = make_report(LIFT, outcomes(3, 6)) | {"kitbench_version": "0.0.1"}
    assert cli.main(["compare", *pair(tmp_path, a, b)]) == 0
    assert "kitbench compare: warning: kitbench_version differs: A " in capsys.readouterr().err


# ----------------------------------------------------------------------------------------------------------------
# the command line


def test_fail_if_worse_sets_the_exit_status(tmp_path, capsys):
    good = make_report(LIFT, outcomes(18, 20), seeds=SEEDS)
    bad = make_report(LIFT, outcomes(8, 20), seeds=SEEDS)
    del bad["per_episode"]  # unpaired: Fisher's test
    a, b = pair(tmp_path, good, bad)
    p = fisher_p(18, 20, 8, 20)
    assert p < 0.05
    assert cli.main(["compare", a, b, "--fail-if-worse"]) == 1
    last = capsys.readouterr().out.splitlines()[-1]
    assert last == f"verdict: B is worse than A (success 90.0% -> 40.0%, Fisher p = {p:.3g} < alpha 0.05)"
    assert cli.main(["compare", a, b]) == 0  # no gate asked for
    assert cli.main(["compare", b, a, "--fail-if-worse"]) == 0  # better
    assert cli.main(["compare", a, b, "--fail-if-worse", "--alpha", str(p / 2)]) == 0  # not significant there
    assert capsys.readouterr().out.splitlines()[-1].startswith("verdict: no significant difference (success 90.0%")


def test_json_output(tmp_path, capsys):
    a = make_report(LIFT, outcomes(4, 12), policy="old")
    b = make_report(LIFT, outcomes(12, 12), policy="new")
    out = tmp_path / "comparison.json"
    assert cli.main(["compare", *pair(tmp_path, a, b), "--json", str(out)]) == 0
    printed = capsys.readouterr().out.splitlines()
    data = json.loads(out.read_text())
    assert data["a"]["policy"] == "old" and data["b"]["policy"] == "new"
    assert data["a"]["path"].endswith("a/report.json") and data["same_suite"] is True
    assert (data["paired"], data["headline_test"], data["unpaired_test"]) == (True, "mcnemar", "fisher")
    assert data["alpha"] == 0.05 and data["warnings"] == []
    verdict = data["verdict"]
    assert verdict["outcome"] == "better" and verdict["line"] == printed[-1]
    assert verdict["p"] == pytest.approx(mcnemar_p(0, 8)) and verdict["difference"] == pytest.approx(8 / 12)
    success = data["rows"][0]
    assert success["section"] == "success" and success["a"] == {"count": 4, "episodes": 12, "rate": 4 / 12}
    assert success["paired"] | {"p": None, "ci95": None} == {
        "test": "mcnemar",
        "a_only": 0,
        "b_only": 8,
        "both": 4,
        "neither": 0,
        "p": None,
        "ci95": None,
    }
    assert success["unpaired"]["p"] == pytest.approx(fisher_p(4, 12, 12, 12), rel=1e-9)
    assert success["ci95"] == pytest.approx(list(newcombe_paired_interval(0, 8, 4, 0)))
    # every failure category of the task is there, even those neither report has
    failures = [r["name"] for r in data["rows"] if r["section"] == "failure"]
    assert failures == list(a["failure_categories"])


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["MISSING", "B"], "no report at "),
        (["A", "B", "--alpha", "1.5"], "alpha must be a number between 0 and 1 (exclusive), got '1.5'"),
        (["A", "B", "--alpha", "five"], "alpha must be a number between 0 and 1 (exclusive), got 'five'"),
        (["A", "B", "--test", "t"], "unknown test 't'; valid choices: fisher, barnard"),
        (["A", "NOT_JSON"], "is not a kitbench report: cannot read it as JSON"),
        (["A", "NOT_REPORT"], "is not a kitbench report: no 'report_version'"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, args, message):
    a, b = pair(tmp_path, make_report(LIFT, outcomes(1, 2)), make_report(LIFT, outcomes(2, 2)))
    (tmp_path / "not.json").write_text("# a report\n")
    (tmp_path / "other.json").write_text('{"success": 1}')
    paths = {"A": a, "B": b, "MISSING": str(tmp_path / "nope"), "NOT_JSON": str(tmp_path / "not.json")}
    paths["NOT_REPORT"] = str(tmp_path / "other.json")
    assert cli.main(["compare", *[paths.get(x, x) for x in args]]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1
    assert err.startswith("kitbench compare: error: ") and message in err


def test_a_report_folder_is_accepted(tmp_path, capsys):
    a, b = pair(tmp_path, make_report(LIFT, outcomes(1, 2)), make_report(LIFT, outcomes(2, 2)))
    assert cli.main(["compare", str(Path(a).parent), str(Path(b).parent)]) == 0
    assert capsys.readouterr().out.splitlines()[-1].startswith("verdict: ")


# ----------------------------------------------------------------------------------------------------------------
# real reports


def _keys(report: dict) -> dict:
    """The structure the comparison reads: top-level keys and the keys of its sections and episodes."""
    return {
        "top": set(report) - {"timing", "output", "provenance"},  # read where a report has it
        "suite": set(report["suite"]),
        "success": set(report["success"]),
        "criteria": {name: set(r) for name, r in report["criteria"].items()},
        "failure_categories": set(report["failure_categories"]),
        "episode": set(report["per_episode"][0]),
    }


def test_real_reports_round_trip(tmp_path, capsys):
    suite = load_suite(ROOT / "eval/suites/lift_peg_upright_short.toml").first(3)
    reports = {
        policy: run_eval(EvalConfig.of(suite, policy, tmp_path / policy), progress=False)
        for policy in ("zero", "expert")
    }
    synthetic = make_report(LIFT, outcomes(2, 3), seeds=suite.seeds)
    assert _keys(synthetic) == _keys(reports["expert"]) == _keys(reports["zero"])
    expert, zero = (str(tmp_path / p / "report.json") for p in ("expert", "zero"))
    out = tmp_path / "cmp.json"
    # 3 seeds cannot show a significant drop, however large: the gate stays open
    assert cli.main(["compare", expert, zero, "--fail-if-worse", "--json", str(out)]) == 0
    lines = capsys.readouterr().out.splitlines()
    data = json.loads(out.read_text())
    s_expert, s_zero = reports["expert"]["success"], reports["zero"]["success"]
    assert data["paired"] is True and data["headline_test"] == "mcnemar"
    row = data["rows"][0]
    assert (row["a"]["count"], row["b"]["count"]) == (s_expert["count"], s_zero["count"])
    only_expert = sum(
        e["success"] and not z["success"]
        for e, z in zip(reports["expert"]["per_episode"], reports["zero"]["per_episode"], strict=True)
    )
    only_zero = sum(
        z["success"] and not e["success"]
        for e, z in zip(reports["expert"]["per_episode"], reports["zero"]["per_episode"], strict=True)
    )
    assert row["p"] == pytest.approx(mcnemar_p(only_expert, only_zero))
    assert lines[-1] == data["verdict"]["line"]
    assert lines[-1].startswith(
        f"verdict: no significant difference (success {s_expert['rate']:.1%} -> {s_zero['rate']:.1%}, McNemar p = "
    )
