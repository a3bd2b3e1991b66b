"""`kitbench select`: every checkpoint of a training run scored on a validation suite's seeds, each an ordinary
resumable report, a table and a plot naming the best; a test suite refused in one line, nothing written."""

from __future__ import annotations

import json
import os
import re
import sys
from pathlib import Path

import pytest

import kitbench
from kitbench import faults
from kitbench.cli import main
from kitbench.errors import KitbenchError
from kitbench.evaluation.report import without_timing
from kitbench.evaluation.select import check_validation_suite, verdict
from kitbench.evaluation.suite import load_suite
from tests import launch

ROOT = Path(__file__).resolve().parents[1]
SUITES = sorted((ROOT / "eval" / "suites").glob("*.toml"))
VAL = "lift_peg_upright_val"


def _select(train: Path, out: Path, *extra: str) -> int:
    return main(["select", str(train), "--suite", VAL, "--episodes", "1", "--device", "cpu", "--out", str(out), *extra])


@pytest.fixture(scope="module")
def selected(tiny_act_run, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("select") / "sel"
    assert _select(tiny_act_run, out) == 0
    return out


# -- which suites select on -----------------------------------------------------------------------------------
def test_validation_suites_declare_their_purpose_and_share_no_seed_with_any_test_suite():
    suites = {p.stem: load_suite(p) for p in SUITES}
    val = {name for name, s in suites.items() if s.purpose == "validation"}
    assert val == {name for name in suites if name.endswith("_val")}
    assert {suites[name].task for name in val} == set(kitbench.TASKS)
    tested = set().union(*(s.seeds for s in suites.values() if s.purpose == "test"))
    for name in val:
        assert not set(suites[name].seeds) & tested, name
        check_validation_suite(suites[name])


def test_a_validation_suite_sharing_a_seed_with_a_test_suite_is_refused(tmp_path):
    path = tmp_path / "leaky_val.toml"
    path.write_text('task = "LiftPegUpright-v1"\nseeds = [3000000, 1000042]\npurpose = "validation"\n')
    with pytest.raises(KitbenchError, match=r"shares 1 seed.*test suite lift_peg_upright.*first 1000042"):
        check_validation_suite(load_suite(path))


def test_an_unknown_purpose_is_refused_naming_the_valid_ones(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text('task = "LiftPegUpright-v1"\nseeds = [3000000]\npurpose = "tuning"\n')
    with pytest.raises(KitbenchError, match="unknown purpose 'tuning'; valid choices: test, validation"):
        load_suite(path)


@pytest.mark.parametrize(
    "args,message",
    [
        (["--suite", "lift_peg_upright"], "is a test suite.*valid choices: lift_peg_upright_val"),
        (["--suite", "eval/suites/lift_peg_upright_heldout.toml"], "is a test suite"),
        (["--suite", VAL, "--steps", "3"], "step 3 is not saved in .*; valid choices: 1, 2"),
        ([], "give --suite, a validation suite; valid choices: assembling_kits_val, lift_peg_upright_val"),
    ],
    ids=["test-suite", "heldout-suite", "unsaved-step", "no-suite"],
)
def test_select_refuses_in_one_line_writing_nothing(tiny_act_run, tmp_path, capsys, args, message):
    out = tmp_path / "sel"
    assert main(["select", str(tiny_act_run), "--out", str(out), *args]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("kitbench select: error: ")
    assert re.search(message, err), err
    assert not out.exists()


def test_select_refuses_a_folder_without_checkpoints(tmp_path, capsys):
    assert main(["select", str(tmp_path), "--suite", VAL, "--out", str(tmp_path / "sel")]) == 2
    assert "no checkpoint in" in capsys.readouterr().err and not (tmp_path / "sel").exists()


# -- scoring ---------------------------------------------------------------------------------------------------
def test_each_checkpoint_is_an_ordinary_report_on_the_validation_seeds(selected, tiny_act_run):
    val_seeds = list(load_suite(ROOT / "eval/suites" / f"{VAL}.toml").seeds[:1])
    for step in (1, 2):
        report = json.loads((selected / f"{step:06d}" / "report.json").read_text())
        weights = report["provenance"]["policy"]["checkpoint"]
        assert weights["training_step"] == step
        assert weights["path"] == str((tiny_act_run / "checkpoints" / f"{step:06d}" / "pretrained_model").resolve())
        assert report["suite"]["seeds"] == val_seeds and report["suite"]["name"] == VAL
        assert not (selected / f"{step:06d}" / "journal").exists()  # finished
    summary = json.loads((selected / "select.json").read_text())
    assert [r["step"] for r in summary["rows"]] == [1, 2]
    for row in summary["rows"]:
        report = json.loads((selected / row["report"] / "report.json").read_text())
        assert (row["successes"], row["episodes"], row["ci95"]) == (
            report["success"]["count"],
            report["success"]["episodes"],
            report["success"]["ci95"],
        )
    best = max(summary["rows"], key=lambda r: (r["rate"], r["step"]))
    assert summary["best_step"] == best["step"] and summary["last_step"] == 2
    md = (selected / "select.md").read_text()
    assert "| 1 |" in md and "| 2 |" in md and verdict(summary) in md
    assert (selected / "select.png").stat().st_size > 1000


def _summary(best: float, last: float, n: int = 20) -> dict:
    from kitbench.evaluation.stats import rate

    rows = []
    for step, p in ((100, best), (200, last)):
        r = rate(round(p * n), n)
        rows.append({"step": step, "successes": r["count"], "episodes": n, "rate": r["rate"], "ci95": r["ci95"]})
    b, la = rows[0], rows[1]
    overlap = b["ci95"][0] <= la["ci95"][1] and la["ci95"][0] <= b["ci95"][1]
    return {"rows": rows, "best_step": 100, "last_step": 200, "best_is_last": False, "best_overlaps_last": overlap,
            "best_vs_last_mcnemar_p": 0.01}  # fmt: skip


def test_the_verdict_says_whether_the_best_interval_overlaps_the_last():
    assert "do not overlap" in verdict(_summary(0.95, 0.30))
    assert "intervals overlap" in verdict(_summary(0.60, 0.55))


# -- resume ----------------------------------------------------------------------------------------------------
def test_a_killed_selection_resumes_into_the_uninterrupted_reports(selected, tiny_act_run, tmp_path, capsys):
    out = tmp_path / "sel"
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "PYTHONPATH": str(ROOT), faults.VAR: "eval.journaled:1"}
    env.pop(faults.OWNER_VAR, None)
    args = [sys.executable, "-m", "kitbench.cli", "select", str(tiny_act_run), "--suite", VAL, "--episodes", "1"]
    killed = launch.run([*args, "--device", "cpu", "--out", str(out)], env=env, capture_output=True, timeout=300)
    assert killed.returncode == -9, killed.stderr[-2000:]
    assert (out / "000001" / "journal").is_dir() and not (out / "select.json").exists()
    # rerun as it was: refused, nothing changed
    assert _select(tiny_act_run, out) == 2
    assert "holds a checkpoint selection already; continue it with --resume" in capsys.readouterr().err
    assert _select(tiny_act_run, out, "--resume") == 0
    for step in ("000001", "000002"):
        resumed = json.loads((out / step / "report.json").read_text())
        twin = json.loads((selected / step / "report.json").read_text())
        assert without_timing(resumed) == without_timing(twin)
    first = json.loads((out / "select.json").read_text())
    assert first["rows"] == json.loads((selected / "select.json").read_text())["rows"]
    # a finished selection resumed again keeps its reports (nothing scored) and writes the same table
    stamps = {p: p.stat().st_mtime_ns for p in out.glob("0*/report.json")}
    assert _select(tiny_act_run, out, "--resume") == 0
    assert {p: p.stat().st_mtime_ns for p in out.glob("0*/report.json")} == stamps
    assert json.loads((out / "select.json").read_text()) == first
    # ... but not with other seeds
    assert main(["select", str(tiny_act_run), "--suite", VAL, "--episodes", "2", "--out", str(out), "--resume"]) == 2
    assert "cannot resume" in capsys.readouterr().err
    assert {p: p.stat().st_mtime_ns for p in out.glob("0*/report.json")} == stamps
