"""bench/structure.py: which module is above which, read from the imports the way the benchmark counts a call
that climbs back up a layer (module level and in-function imports; TYPE_CHECKING ones only for the types a module
knows; relative imports resolved)."""

from __future__ import annotations

from pathlib import Path

from bench.structure import below, module_imports


def _package(root: Path, files: dict[str, str]) -> Path:
    package = root / "kitbench"
    for name, text in files.items():
        path = package / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return package


def test_imports_are_read_at_module_level_in_functions_and_relative_and_type_checking_only_when_asked(tmp_path):
    package = _package(
        tmp_path,
        {
            "__init__.py": "",
            "base.py": "",
            "envs/__init__.py": "",
            "envs/env.py": "from kitbench import base\n",
            "envs/task.py": "from .env import X\n\ndef f():\n    import kitbench.cli\n",
            "cli.py": (
                "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from kitbench.envs import task\n"
                "from kitbench.base import y\n"
            ),
        },
    )
    graph = module_imports(package)
    assert graph["kitbench.envs.env"] == {"kitbench.base"}
    assert graph["kitbench.envs.task"] == {"kitbench.envs.env", "kitbench.cli"}  # relative, and inside a function
    assert graph["kitbench.cli"] == {"kitbench.base"}  # a TYPE_CHECKING import runs nothing
    assert module_imports(package, typing_only=True)["kitbench.cli"] == {"kitbench.base", "kitbench.envs.task"}


def test_below_is_every_module_a_module_reaches_through_its_imports():
    graph = {"a": {"b"}, "b": {"c"}, "c": set(), "d": {"a", "c"}}
    reach = below(graph)
    assert reach["a"] == {"b", "c"} and reach["d"] == {"a", "b", "c"} and reach["c"] == set()
    # a call from c into a is a climb (a imports c, through b); from a into c it goes down
    assert "c" in reach["a"] and "a" not in reach["c"]
