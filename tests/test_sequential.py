"""`kitbench race` and its group-sequential paired test (`kitbench.evaluation.sequential`): the test's error rate at
no difference stays within alpha however often it is looked at, the race stops early on a clear difference and
leaves two ordinary reports `kitbench compare` reads, a killed race resumes into the race an uninterrupted one
runs, `kitbench eval --stop-after` extends by `--resume` into the uninterrupted report, and bad input is one line."""

from __future__ import annotations

import json
import math
import os
import signal
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import stats  # type: ignore[import-untyped]

from bench.sequential_sim import naive_repeated, pair_probabilities, race, simulate
from kitbench import faults
from kitbench.cli import main
from kitbench.evaluation import sequential
from kitbench.evaluation.compare import compare_reports
from kitbench.evaluation.config import eval_config
from kitbench.evaluation.race import race_config, run_race
from kitbench.evaluation.runner import run_eval
from tests import launch

ROOT = Path(__file__).resolve().parents[1]
SUITE = ROOT / "eval" / "suites" / "lift_peg_upright.toml"  # 100 seeds: room to stop early
SHORT = ROOT / "eval" / "suites" / "lift_peg_upright_short.toml"
RACE = ["--a", "expert", "--b", "zero", "--suite", str(SUITE), "--block", "5"]


# -- the test --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("p", "rho", "block"), [(0.7, 0.5, 10), (0.9, 0.0, 1)])
def test_error_rate_at_no_difference_stays_within_alpha(p, rho, block):
    """4,000 simulated races of two equal policies on 200 seeds (fixed seed): the race decides in at most alpha of
    them, looked at every 10 seeds or after every seed; McNemar's fixed-N test repeated at the same looks does not
    (so the bound is one a wrong test fails)."""
    alpha = 0.05
    a_only, b_only = simulate(*pair_probabilities(p, p, rho), 4000, 200, np.random.default_rng(7))
    decision, used = race(a_only, b_only, alpha, block)
    assert np.mean(decision != 0) <= alpha
    assert np.mean(naive_repeated(a_only, b_only, alpha, block)) > alpha
    assert used.max() == 200


def _first_crossings(signs: np.ndarray, ks, lower, upper) -> np.ndarray:
    """Each sign sequence's first look at which S crossed: +1 upper, -1 lower, 0 never (per look, one-hot)."""
    out = np.zeros((len(signs), len(ks)), dtype=np.int64)
    alive = np.ones(len(signs), dtype=bool)
    for j, k in enumerate(ks):
        s = signs[:, :k].sum(axis=1)
        hit = np.where(s >= upper[j], 1, np.where(s <= lower[j], -1, 0)) * alive
        out[:, j] = hit
        alive &= hit == 0
    return out


@pytest.mark.parametrize("theta", [0.5, 0.3])
def test_boundaries_spend_what_the_spending_function_allows_and_no_less(theta):
    """Every sequence of 12 discordant seeds enumerated: at each look, each side's chance of a first crossing so
    far is at most alpha/2 * t^rho, and moving that look's boundary one seed inwards would exceed it."""
    ks, fractions, alpha = [3, 6, 8, 12], [0.25, 0.5, 0.75, 1.0], 0.3
    signs = (np.arange(2**12)[:, None] >> np.arange(12)) & 1
    weights = np.prod(np.where(signs == 1, theta, 1 - theta), axis=1)
    lower, upper = (b[0] for b in sequential.boundaries(ks, fractions, alpha, theta))
    assert (upper[:-1] <= np.array(ks[:-1])).any() and (lower >= 0).any()  # the case does cross somewhere
    checked = 0
    for j in range(len(ks)):
        allowed = sequential.spent(fractions[j], alpha / 2)
        for side, bound in ((1, upper), (-1, lower)):
            crossed = _first_crossings(signs, ks, lower, upper)[:, : j + 1]
            assert weights @ (crossed == side).any(axis=1) <= allowed + 1e-12
            inward = bound.copy()
            inward[j] -= side  # one seed nearer the middle
            if (inward[j] - lower[j]) * (upper[j] - inward[j]) <= 0:
                continue  # it would meet the other side's boundary
            moved = (lower, inward) if side == 1 else (inward, upper)
            crossed = _first_crossings(signs, ks, *moved)[:, : j + 1]
            assert weights @ (crossed == side).any(axis=1) > allowed, (theta, j, side)
            checked += 1
    assert checked >= 6


def test_decision_and_interval_agree_and_the_interval_ends_where_theta_is_rejected():
    """At random looks of random races: the test decides exactly when the difference's interval leaves out 0, on
    the interval's side; theta's interval holds the estimate and its ends are where theta's own test turns."""
    rng = np.random.default_rng(5)
    for _ in range(40):
        total = int(rng.choice([50, 100, 200]))
        theta, d = rng.uniform(0.2, 0.95), rng.uniform(0.1, 0.6)
        outcome = rng.choice(3, size=total, p=[d * theta, d * (1 - theta), 1 - d])
        a_only, b_only = np.cumsum(outcome == 0), np.cumsum(outcome == 1)
        at = list(range(10, total + 1, 10))[: rng.integers(1, 8)]
        looks = [(n, int(a_only[n - 1]), int(b_only[n - 1])) for n in at]
        r = sequential.assess(looks, total, 0.05)
        low, high = r.interval
        assert low <= r.difference <= high
        assert r.decided == (low > 0 or high < 0)
        if r.decided:
            assert r.decision == (sequential.A_BETTER if low > 0 else sequential.B_BETTER)
        s, k = r.a_only, r.a_only + r.b_only
        t_lo, t_hi = r.theta_interval
        assert t_lo <= (s / k if k else 0.5) <= t_hi
        ks, fractions = [a + b for _, a, b in looks], [n / total for n, _, _ in looks]
        for end, outwards in ((t_lo, -1), (t_hi, 1)):
            if 0 < end < 1 and abs(end - 0.5) > 1e-6:
                for theta_, kept in ((end - outwards * 1e-6, True), (end + outwards * 1e-6, False)):
                    lower, upper = sequential.boundaries(ks, fractions, 0.045, theta_)
                    assert (lower[0, -1] < s < upper[0, -1]) == kept, (looks, end, theta_)


def test_repeated_intervals_hold_theta_at_every_look_at_once():
    """2,000 runs of 200 seeds at theta = 0.7, D = 0.4, looked at every 10 seeds: theta's own test (whose
    inversion is the interval) rejects the truth at some look in at most alpha of them, and spends nearly all of
    it (a test that kept far more would be needlessly slow)."""
    rng = np.random.default_rng(11)
    runs, theta, alpha = 2000, 0.7, 0.045
    discordant = rng.random((runs, 200)) < 0.4
    wins = discordant & (rng.random((runs, 200)) < theta)
    at = np.arange(10, 201, 10)
    ks, s = np.cumsum(discordant, axis=1)[:, at - 1], np.cumsum(wins, axis=1)[:, at - 1]
    lower, upper = sequential.boundaries(ks, at / 200, alpha, theta)
    missed = np.mean(((s <= lower) | (s >= upper)).any(axis=1))
    assert missed <= alpha + 2 * math.sqrt(alpha * (1 - alpha) / runs)
    assert missed >= alpha / 2


def test_theta_interval_covers_at_every_look():
    """Robbins' interval of theta holds the truth at every n at once in at least 1 - alpha of the runs."""
    rng = np.random.default_rng(3)
    theta, runs, n = 0.7, 300, 120
    wins = np.cumsum(rng.random((runs, n)) < theta, axis=1)
    missed = 0
    for run in wins:
        for k in range(10, n + 1, 10):
            lo, hi = sequential._mixture_interval(int(run[k - 1]), k, 0.05, (1.0, 1.0))
            if not lo <= theta <= hi:
                missed += 1
                break
    assert missed / runs <= 0.05 + 2 * math.sqrt(0.05 * 0.95 / runs)
    assert stats.binom(runs, 0.05).sf(missed) > 1e-6


# -- the race ------------------------------------------------------------------------------------------------------
def _flags(out: Path, *extra: str) -> dict:
    from kitbench.cli import build_parser

    args = build_parser().parse_args(["race", *RACE, "--out", str(out), *extra])
    from kitbench.cli import COMMANDS, _imported
    from kitbench.config.flags import given

    flags: dict = {}
    for config, only in COMMANDS["race"].settings:
        flags.update({k: v for k, v in given(_imported(config), args).items() if only is None or k in only})
    return flags


def _without_timing(folder: Path) -> dict:
    report = json.loads((folder / "report.json").read_text())
    del report["timing"], report["provenance"]["command"]
    return report


@pytest.fixture(scope="module")
def finished_race(tmp_path_factory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("race") / "race"
    race_json = run_race(race_config(_flags(out)), progress=False, say=lambda line: None)
    return out, race_json


def test_race_stops_early_and_leaves_reports_compare_reads(finished_race):
    """The expert against a policy that never succeeds: every seed favours A, and the race decides after 10 of the
    suite's 100 seeds; each side's report is an ordinary report of those 10 seeds (its journal kept for
    `kitbench eval --resume`), and `kitbench compare` finds B worse on them."""
    out, race_json = finished_race
    assert race_json["finished"] and race_json["decision"] == sequential.A_BETTER
    assert race_json["episodes"] == 10 and race_json["suite_episodes"] == 100
    assert race_json["interval"][0] > 0 and race_json["difference"] == 1.0
    assert [look["pairs"] for look in race_json["looks"]] == [5, 10]
    assert json.loads((out / "race.json").read_text()) == race_json
    for side in ("a", "b"):
        report = json.loads((out / side / "report.json").read_text())
        assert report["episodes"] == 10 and report["partial"] == {"episodes": 10, "suite_episodes": 100}
        assert report["suite"]["seeds"] == list(range(1_000_000, 1_000_010))
        assert (out / side / "journal" / "results.jsonl").is_file()
    comparison = compare_reports(out / "a", out / "b")
    assert comparison.verdict == "worse" and comparison.paired and comparison.same_suite


def test_killed_race_resumes_into_the_uninterrupted_race(finished_race, tmp_path):
    """A race killed (SIGKILL) in A's second block, then `kitbench race --resume`: the same race.json and the same
    two reports as the race that was never stopped."""
    twin, race_json = finished_race
    out = tmp_path / "race"
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "PYTHONPATH": str(ROOT), faults.VAR: "eval.journaled:13"}
    env.pop(faults.OWNER_VAR, None)
    command = [sys.executable, "-m", "kitbench.cli", "race", *RACE, "--out", str(out)]
    killed = launch.run(command, env=env, capture_output=True, text=True, timeout=300)
    assert killed.returncode == -signal.SIGKILL, killed.stderr[-2000:]
    assert not json.loads((out / "race.json").read_text())["finished"]
    del env[faults.VAR]
    resumed = launch.run([*command, "--resume"], env=env, capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    assert "decision: A better" in resumed.stdout and "episodes used: 10 of the suite's 100" in resumed.stdout
    assert json.loads((out / "race.json").read_text()) == race_json
    for side in ("a", "b"):
        assert _without_timing(out / side) == _without_timing(twin / side)


def test_stop_after_then_resume_equals_the_uninterrupted_report(tmp_path):
    """`kitbench eval --stop-after 4`, then `--resume --stop-after 7`, then `--resume`: the report of the whole
    suite an uninterrupted run writes, its journal gone."""
    flags = {"suite_file": SHORT, "policy": "expert"}
    whole = run_eval(eval_config({**flags, "out": tmp_path / "whole"}), progress=False)
    steps = eval_config({**flags, "out": tmp_path / "steps"})
    first = run_eval(steps.replace(stop_after=4), progress=False)
    assert first["episodes"] == 4 and first["partial"]["suite_episodes"] == 10
    run_eval(steps.replace(stop_after=7, resume=True), progress=False)
    last = run_eval(steps.replace(resume=True), progress=False)
    assert "partial" not in last and not (tmp_path / "steps" / "journal").exists()
    for report in (whole, last):
        del report["timing"]
    assert last == whole


@pytest.mark.parametrize(
    ("extra", "says"),
    [
        (["--alpha", "1.5"], "alpha must be a number between 0 and 1"),
        (["--alpha", "0"], "alpha must be a number between 0 and 1"),
        (["--block", "0"], "block must be a positive integer"),
        (["--b", "expert"], "A and B are the same policy"),
        (["--suite", "lift_peg_upright_robustness"], "is a robustness suite"),
        (["--resume"], "holds no race (race.json) to resume"),
        (["--resume", "--overwrite"], "--resume and --overwrite exclude each other"),
    ],
)
def test_bad_input_is_one_line_and_writes_nothing(tmp_path, capsys, extra, says):
    out = tmp_path / "race"
    code = main(["race", *RACE, "--out", str(out), *extra])
    err = capsys.readouterr().err
    assert code == 2 and says in err and err.count("\n") == 1, err
    assert not out.exists()


def test_resume_with_other_settings_or_a_finished_race_is_refused(finished_race, capsys):
    out, _ = finished_race
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    for extra, says in ((["--block", "6", "--resume"], "block: race 5, now 6"), (["--resume"], "finished race")):
        code = main(["race", *RACE, "--out", str(out), *extra])
        err = capsys.readouterr().err
        assert code == 2 and says in err and err.count("\n") == 1, err
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before


def test_a_race_begun_under_another_test_is_not_resumed(finished_race, tmp_path, capsys):
    """A race whose race.json names another test (the mixture test of race.json version 1): --resume is refused in
    one line naming the test, nothing changed."""
    import shutil

    out = tmp_path / "race"
    shutil.copytree(finished_race[0], out)
    stored = json.loads((out / "race.json").read_text())
    stored["settings"]["test"] = {"name": "mixture sequential probability ratio test of McNemar's discordant seeds"}
    stored["finished"] = False
    (out / "race.json").write_text(json.dumps(stored))
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    code = main(["race", *RACE, "--out", str(out), "--resume"])
    err = capsys.readouterr().err
    assert code == 2 and "test: race {'name': \"mixture" in err and err.count("\n") == 1, err
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
