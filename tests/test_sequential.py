"""`kitbench race` and its anytime-valid paired test (`kitbench.evaluation.sequential`): the test's error rate at
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
from scipy import integrate, stats  # type: ignore[import-untyped]

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


def test_evidence_is_the_mixture_likelihood_ratio():
    """M_n(theta) against the integral it stands for (uniform prior), and the decision with its intervals: the
    test decides exactly when the difference's interval leaves out 0, whose sign is the decision's."""
    s, n, theta = 9, 12, 0.4
    integral = integrate.quad(lambda q: q**s * (1 - q) ** (n - s), 0, 1)[0] / (theta**s * (1 - theta) ** (n - s))
    assert math.isclose(math.exp(sequential.log_evidence(s, n, theta=theta)), integral, rel_tol=1e-9)
    for pairs in (10, 40):
        for a_only in range(0, pairs + 1, 3):
            for b_only in range(0, pairs - a_only + 1, 3):
                r = sequential.assess(pairs, a_only, b_only, 0.05)
                low, high = r.interval
                assert low <= r.difference <= high
                assert r.decided == (low > 0 or high < 0)
                assert r.decision == (
                    sequential.A_BETTER if low > 0 else sequential.B_BETTER if high < 0 else r.decision
                )
                assert (r.evidence >= r.threshold) == r.decided


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
