"""`make test` leaves out the cases marked slow, `make test-all` (CI) runs them: a slow case must be another case of
a test whose other cases `make test` runs, never the only one (tests/conftest.py refuses the collection)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CASES = """
import pytest

@pytest.mark.parametrize("n", [1, pytest.param(2, marks=pytest.mark.slow)])
def test_twinned(n):
    assert n in (1, 2)
"""
ALONE = """
@pytest.mark.slow
def test_alone():
    pass
"""


def _collect(folder: Path, text: str, *args: str) -> subprocess.CompletedProcess:
    (folder / "conftest.py").write_text((ROOT / "tests" / "conftest.py").read_text())
    (folder / "test_cases.py").write_text(text)
    command = [sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider", "-p", "no:xdist"]
    # the project's markers, from pyproject.toml, as an ini of the folder's own
    (folder / "pytest.ini").write_text("[pytest]\nmarkers =\n    slow: as the project's\n")
    return subprocess.run([*command, *args, str(folder)], capture_output=True, text=True, cwd=folder, timeout=120)


def test_make_test_leaves_out_the_slow_case_and_make_test_all_runs_it(tmp_path):
    fast = _collect(tmp_path, CASES, "-m", "not slow")
    every = _collect(tmp_path, CASES)
    assert fast.returncode == 0 and every.returncode == 0, fast.stdout + fast.stderr
    assert "test_twinned[1]" in fast.stdout and "test_twinned[2]" not in fast.stdout
    assert "test_twinned[1]" in every.stdout and "test_twinned[2]" in every.stdout


def test_a_slow_test_with_no_case_left_in_make_test_is_refused_in_one_line(tmp_path):
    run = _collect(tmp_path, CASES + ALONE)
    assert run.returncode != 0
    lines = [line for line in (run.stdout + run.stderr).splitlines() if "marked slow" in line]
    assert len(lines) == 1 and "test_alone" in lines[0] and "test_twinned" not in lines[0], run.stdout + run.stderr
