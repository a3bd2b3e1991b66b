"""The files kitbench ships beside its code: the lerobot-train configs and their published figures (`policies/`),
the evaluation suites (`eval/suites/`) and the recording recipes (`datasets/`).

A checkout reads them from its source tree. A wheel carries a copy inside the package, `kitbench/_shipped/` in
the same layout (`hatch_build.py` packs it), so `ROOT / "policies"` means the same in both, and `kitbench
reproduce`, `kitbench demo` and `kitbench eval --suite <name>` work installed. `find` lets a command that names a
shipped file as the checkout's documentation does (`eval/suites/lift_peg_upright.toml`), or by its bare name, run
from any folder.
"""

from __future__ import annotations

from pathlib import Path

from kitbench.errors import check_choice

PACKAGE = Path(__file__).resolve().parent
CHECKOUT = PACKAGE.parent
PACKED = PACKAGE / "_shipped"  # hatch_build.py packs the files here
# the checkout the package sits in when it has the shipped files, else the wheel's copy of them
ROOT = CHECKOUT if (CHECKOUT / "policies" / "published.toml").is_file() else PACKED
# What each kind of file is found among, by the folder it is shipped in.
FOLDERS = {"suite": "eval/suites", "recipe": "datasets"}


def names(kind: str) -> list[str]:
    """The shipped files of `kind` ("suite", "recipe") by their bare names."""
    return sorted(p.stem for p in (ROOT / FOLDERS[kind]).glob("*.toml"))


def find(path: str | Path, kind: str) -> Path:
    """`path` where it exists; else the shipped file it names, as a path relative to the checkout
    (`eval/suites/lift_peg_upright.toml`) or by its bare name (`lift_peg_upright`). A bare name that names none is
    refused in one line listing the shipped ones; any other path is returned as given, for its reader to refuse."""
    given = Path(path)
    if given.exists() or given.is_absolute():
        return given
    folder = ROOT / FOLDERS[kind]
    for candidate in (ROOT / given, folder / given, folder / f"{given}.toml"):
        if candidate.is_file():
            return candidate
    if given.suffix == "" and len(given.parts) == 1:
        check_choice(kind, str(path), names(kind))
    return given
