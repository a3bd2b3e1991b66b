"""The studies stay apart from the product: docs/learnability.md is the method and an index, each study in
docs/studies/ reads question, set-up, result, decision with a command that runs, every benchmark in bench/ is
listed in bench/README.md, and no file points at a script that is not there."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
STUDIES = sorted((ROOT / "docs" / "studies").glob("*.md"))
SECTIONS = ("## Question", "## Set-up", "## Result", "## Decision")
# a path into the project's scripts, recipes, configs and suites, as docs and code name them
PROJECT_PATH = re.compile(
    r"(?<![\w/.-])((?:bench|studies)/[\w/.-]+\.(?:py|sh)|(?:datasets|eval/suites)/\w+\.toml|policies/\w+\.json)"
)


def _sections(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.startswith("## ")]


def test_learnability_is_an_index_of_at_most_300_lines_linking_every_study():
    text = (ROOT / "docs" / "learnability.md").read_text()
    assert len(text.splitlines()) <= 300
    linked = set(re.findall(r"\]\(studies/([\w-]+\.md)\)", text))
    assert linked == {p.name for p in STUDIES}


@pytest.mark.parametrize("doc", STUDIES, ids=[p.stem for p in STUDIES])
def test_a_study_reads_question_set_up_result_decision_with_a_command_that_runs(doc):
    text = doc.read_text()
    assert text.startswith("# ")
    assert _sections(text) == list(SECTIONS), f"{doc.name}: sections {_sections(text)}"
    set_up = text.split("## Set-up", 1)[1].split("## Result", 1)[0]
    commands = re.findall(r"```bash\n(.*?)```", set_up, re.S)
    assert commands, f"{doc.name}: its set-up has no ```bash block that reproduces it"
    for path in PROJECT_PATH.findall(text):
        assert (ROOT / path).is_file(), f"{doc.name} names {path}, which is not in the project"


def test_every_benchmark_is_listed_in_the_bench_readme():
    listed = (ROOT / "bench" / "README.md").read_text()
    missing = [p.name for p in sorted((ROOT / "bench").glob("*.py")) if f"`{p.name}`" not in listed]
    assert not missing, f"bench/README.md does not list {missing}"


def test_every_study_script_is_cited_by_a_study():
    cited = "".join(p.read_text() for p in [*STUDIES, ROOT / "studies" / "gpu" / "README.md"])
    scripts = [p for p in (ROOT / "studies").rglob("*") if p.suffix in (".py", ".sh")]
    assert scripts
    uncited = [str(p.relative_to(ROOT)) for p in scripts if p.name not in cited]
    assert not uncited, f"no write-up cites {uncited}"


def test_no_tracked_file_names_a_script_that_is_not_there():
    files = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout.split()
    stale = []
    for name in files:
        path = ROOT / name
        if path.suffix not in (".py", ".md", ".toml", ".sh", ".json", ".cfg", ".txt") and path.name != "Makefile":
            continue
        named = PROJECT_PATH.findall(path.read_text(errors="replace"))
        stale += [f"{name}: {p}" for p in named if p.startswith(("bench/", "studies/")) and not (ROOT / p).is_file()]
    assert not stale, "names of scripts that are not there:\n" + "\n".join(stale)
