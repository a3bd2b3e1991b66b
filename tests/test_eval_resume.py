"""`kitbench eval --resume`: an evaluation killed at any moment (a named fault point, `kitbench.faults`), or stopped
by SIGTERM, resumes into the report an uninterrupted run writes (everything but its timing), with the same videos
and the same `--save-dataset` dataset; what cannot be resumed is refused in one line, changing nothing on disk.

Each run is `kitbench eval` in a folder of its own with `--out report`, so an uninterrupted twin and a resumed run
have the same command line, which the report's provenance names."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

import kitbench  # noqa: F401
from kitbench import faults
from kitbench.evaluation.journal import EvalJournal
from tests import launch
from tests.conftest import VULKAN
from tests.datasets_equal import no_leftovers, same_content

ROOT = Path(__file__).resolve().parents[1]
SHORT = ROOT / "eval" / "suites" / "lift_peg_upright_short.toml"
EPISODES = 6
FILMED = ("--videos", "1") if VULKAN else ()  # filming needs a render device (seconds a video), the scores do not
# saving a dataset (seconds an episode): three episodes show it resumed mid-suite and at each step of its commit
SAVED_EPISODES = 3
SAVE = ("--save-dataset", "ds", "--episodes", str(SAVED_EPISODES))  # the last --episodes counts


def _env() -> dict[str, str]:
    """This process's environment (a Ray cluster's settings included) for a run of this checkout's kitbench."""
    return {**os.environ, "HF_HUB_OFFLINE": "1", "PYTHONPATH": str(ROOT)}


def _eval_args(*extra: str, episodes: int = EPISODES) -> list[str]:
    return [
        sys.executable,
        "-m",
        "kitbench.cli",
        "eval",
        "--suite",
        str(SHORT),
        "--episodes",
        str(episodes),
        "--out",
        "report",
        *extra,
    ]


def _run(folder: Path, args: list[str], fault: str | None = None) -> subprocess.CompletedProcess:
    folder.mkdir(parents=True, exist_ok=True)
    env = _env()
    env.pop(faults.OWNER_VAR, None)
    if fault is not None:
        env[faults.VAR] = fault
    return launch.run(args, cwd=folder, env=env, timeout=600, text=True)


def _ok(folder: Path, args: list[str]) -> subprocess.CompletedProcess:
    run = _run(folder, args)
    assert run.returncode == 0 and "Traceback" not in run.stderr, run.stderr[-3000:]
    return run


def _killed(folder: Path, args: list[str], fault: str) -> None:
    run = _run(folder, args, fault)
    assert run.returncode == -signal.SIGKILL, f"{fault} was not reached (exit {run.returncode}): {run.stderr[-2000:]}"


def _report(out: Path, command: bool) -> dict:
    report = json.loads((out / "report.json").read_text())
    del report["timing"]
    if not command:
        del report["provenance"]["command"]
    return report


def same_report(a: Path, b: Path, command: bool = True) -> None:
    """Two report folders say the same: report.json but for its timing (and the command line unless `command`),
    report.md but for those lines, the same plots and videos, and nothing of the journal left."""
    assert _report(a, command) == _report(b, command)
    skipped = ("Evaluated in",) if command else ("Evaluated in", "- command:")
    md = [[line for line in (f / "report.md").read_text().splitlines() if not line.startswith(skipped)] for f in (a, b)]
    assert md[0] == md[1]
    assert sorted(p.name for p in (a / "plots").iterdir()) == sorted(p.name for p in (b / "plots").iterdir())
    videos = [sorted(p.name for p in (f / "videos").glob("*")) if (f / "videos").exists() else [] for f in (a, b)]
    assert videos[0] == videos[1]
    assert sorted(p.name for p in b.iterdir()) == sorted(p.name for p in a.iterdir())  # no journal, no partials


@pytest.fixture(scope="module")
def twins(tmp_path_factory) -> dict[str, Path]:
    """Uninterrupted runs: unbatched, with a video where this machine can film, at batch size 4, and with
    --save-dataset."""
    base = tmp_path_factory.mktemp("twins")
    flags = {"one": (), "filmed": FILMED, "batch": ("--batch-size", "4"), "save": SAVE}
    for name, extra in flags.items():
        _ok(base / name, _eval_args(*extra))
    return {name: base / name for name in flags}


# case -> (twin, extra flags, the fault point the first run dies at, the episodes the resume reads back)
CASES = {
    "before the first episode": ("one", (), "eval.started", 0),
    "the journal's settings half written": ("one", (), "journal.write:1", 0),
    "after the first episode": ("one", (), "eval.journaled:1", 1),
    "mid-suite": ("one", (), "eval.journaled:4", 4),
    "every episode journaled, no report": ("one", (), "eval.scored", EPISODES),
    "the report written, no videos": ("filmed", FILMED, "eval.reported", EPISODES),
    # unfilmed: a resume that finds videos on disk is the filming kill's test below
    "the report complete, the journal not yet deleted": ("one", (), "eval.finishing", EPISODES),
    "batch size 4, after the first batch": ("batch", ("--batch-size", "4"), "eval.journaled:1", 4),
    "batch size 4, the report written": ("batch", ("--batch-size", "4"), "eval.reported", EPISODES),
    "saving a dataset, mid-suite": ("save", SAVE, "eval.journaled:2", 2),
    "saving a dataset, its commit not in place": ("save", SAVE, "commit.card:1", SAVED_EPISODES),
    "saving a dataset, its commit in place": ("save", SAVE, "commit.swapped:1", SAVED_EPISODES),
}


def _resumed(out: Path) -> int:
    return json.loads((out / "report.json").read_text())["timing"]["resumed_episodes"]


# Cases that repeat a fault point of the same kind as a case make test runs (`make test-all` and CI run them too):
# mid-suite is eval.journaled as after the first episode is (a journal holding some episodes resumed); the filmed
# report written is eval.reported as batch size 4's is (a written report resumed), and a resume films again after
# the filming kill below.
SLOW = {"mid-suite", "the report written, no videos"}
PARAMS = [
    pytest.param(*case, id=name, marks=[pytest.mark.slow] if name in SLOW else []) for name, case in CASES.items()
]


@pytest.mark.parametrize(("twin", "extra", "fault", "kept"), PARAMS)
def test_an_evaluation_killed_at_a_fault_point_resumes_into_the_uninterrupted_report(
    tmp_path, twins, twin, extra, fault, kept
):
    _killed(tmp_path, _eval_args(*extra), fault)
    assert (tmp_path / "report" / "journal").is_dir()  # something to resume
    _ok(tmp_path, _eval_args(*extra, "--resume"))
    same_report(twins[twin] / "report", tmp_path / "report")
    assert _resumed(tmp_path / "report") == kept  # what was journaled is not scored again
    if "--save-dataset" in extra:
        same_content(twins[twin] / "ds", tmp_path / "ds")
        no_leftovers(tmp_path / "ds")


@pytest.mark.skipif(not VULKAN, reason="no Vulkan device: nothing is filmed")
def test_an_evaluation_killed_while_filming_resumes_into_the_uninterrupted_report(tmp_path, twins):
    _killed(tmp_path, _eval_args(*FILMED), "eval.filmed:1")
    _ok(tmp_path, _eval_args(*FILMED, "--resume"))
    same_report(twins["filmed"] / "report", tmp_path / "report")
    assert _resumed(tmp_path / "report") == EPISODES
    assert len(list((tmp_path / "report" / "videos").iterdir())) == 1


def test_a_torn_journal_line_is_scored_again(tmp_path, twins):
    """A power cut may leave the last line cut short: it is dropped and its episode scored again."""
    _killed(tmp_path, _eval_args(), "eval.journaled:3")
    results = EvalJournal(tmp_path / "report").results_path
    lines = results.read_bytes().splitlines(keepends=True)
    results.write_bytes(b"".join(lines[:2]) + lines[2][:40])
    _ok(tmp_path, _eval_args("--resume"))
    same_report(twins["one"] / "report", tmp_path / "report")
    assert _resumed(tmp_path / "report") == 2


def test_sigterm_stops_in_one_line_and_the_run_resumes(tmp_path):
    """SIGTERM ends the run between two journaled episodes, saying how to continue; the resumed report equals
    an uninterrupted one (a policy that runs every episode to its time limit, so the run lasts long enough)."""
    args = _eval_args("--policy", "zero", episodes=6)
    _ok(tmp_path / "twin", args)
    folder = tmp_path / "stopped"
    folder.mkdir()
    proc = launch.start(args, env=_env(), cwd=folder, logs=tmp_path)  # a fork of the test's server, as `_run`'s are
    results = EvalJournal(folder / "report").results_path
    deadline = time.monotonic() + 300
    while proc.poll() is None and time.monotonic() < deadline:
        if results.is_file() and results.read_bytes().count(b"\n") >= 2:
            proc.send_signal(signal.SIGTERM)
            break
        time.sleep(0.01)
    _, stderr = proc.communicate(timeout=300)
    lines = stderr.strip().splitlines()
    assert proc.returncode == 2 and lines[-1].startswith("kitbench eval: error: stopped by SIGTERM"), stderr[-3000:]
    assert "--resume" in lines[-1] and "Traceback" not in stderr
    _ok(folder, [*args, "--resume"])
    same_report(tmp_path / "twin" / "report", folder / "report")
    assert 2 <= _resumed(folder / "report") < 6


# -- refusals ------------------------------------------------------------------------------------------
def _snapshot(root: Path) -> dict[str, tuple[bytes, int]]:
    return {str(p.relative_to(root)): (p.read_bytes(), p.stat().st_mtime_ns) for p in root.rglob("*") if p.is_file()}


@pytest.fixture(scope="module")
def interrupted(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("interrupted")
    _killed(folder, _eval_args(), "eval.journaled:2")
    return folder


REFUSALS = {
    "again without --resume": (
        (),
        "holds an interrupted evaluation (2 episodes scored); continue it with --resume, or pass --overwrite",
    ),
    "another policy": (("--resume", "--policy", "zero"), "policy: journal 'expert', now 'zero'"),
    "another suite": (("--resume", "--episodes", "5"), "suite seeds: journal 6 seeds 1000000…1000005, now 5 seeds"),
    "another batch size": (("--resume", "--batch-size", "2"), "execution batch_size: journal 1, now 2"),
    "another policy option": (("--resume", "--policy-option", "close_steps=8"), "execution policy_options"),
    "--resume with --overwrite": (("--resume", "--overwrite"), "--resume and --overwrite exclude each other"),
}


@pytest.mark.parametrize(("extra", "needle"), REFUSALS.values(), ids=REFUSALS.keys())
def test_what_cannot_resume_is_refused_in_one_line_changing_nothing(interrupted, extra, needle):
    before = _snapshot(interrupted)
    run = _run(interrupted, _eval_args(*extra))  # a flag given twice: the last one counts
    lines = run.stderr.strip().splitlines()
    assert run.returncode == 2 and len(lines) == 1, run.stderr[-3000:]
    assert lines[0].startswith("kitbench eval: error:") and needle in lines[0], lines[0]
    assert _snapshot(interrupted) == before


def test_a_finished_report_is_not_resumed_and_stays(twins):
    folder = twins["one"]
    before = _snapshot(folder)
    run = _run(folder, _eval_args("--resume"))
    assert run.returncode == 2 and run.stderr.count("\n") == 1, run.stderr[-3000:]
    assert "holds a finished evaluation: nothing to resume (pass --overwrite to run it again)" in run.stderr
    assert _snapshot(folder) == before


def test_overwrite_replaces_an_interrupted_evaluation_and_keeps_the_users_files(tmp_path, twins):
    _killed(tmp_path, _eval_args(), "eval.journaled:2")
    (tmp_path / "report" / "notes.txt").write_text("mine")
    _ok(tmp_path, _eval_args("--overwrite"))
    assert (tmp_path / "report" / "notes.txt").read_text() == "mine"
    (tmp_path / "report" / "notes.txt").unlink()
    same_report(twins["one"] / "report", tmp_path / "report", command=False)  # this one said --overwrite
