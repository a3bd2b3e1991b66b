"""The package's shape, checked from its source: no import cycles, no reach-ins into other objects' private
members, and no task named outside the task's own files (so adding a task touches no shared file)."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

from bench.structure import module_imports

PACKAGE = Path(__file__).resolve().parents[1] / "kitbench"
PLUGIN = Path(__file__).resolve().parents[1] / "integrations" / "lerobot_env_kitbench"
# Shared code that must ask tasks through their hooks instead of naming them.
TASK_FREE = ("evaluation", "recording", "policies", "envs", "cli.py", "demo.py", "doctor.py", "registration.py")
TASK_WORDS = re.compile(r"LiftPeg|AssemblingKits|\bpeg\b|shape_id", re.IGNORECASE)


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one member (Tarjan)."""
    index, low, stack, on_stack, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


@pytest.fixture(scope="module")
def module_graph() -> dict[str, set[str]]:
    return module_imports(PACKAGE)


def test_no_import_cycles_between_modules(module_graph):
    assert _cycles(module_graph) == []


def test_no_import_cycles_between_subpackages(module_graph):
    def unit(name: str) -> str:
        return ".".join(name.split(".")[:2])

    graph: dict[str, set[str]] = {}
    for name, targets in module_graph.items():
        if name == "kitbench":  # the package's own __init__ imports its parts to register tasks
            continue
        graph.setdefault(unit(name), set()).update(
            unit(t) for t in targets if unit(t) != unit(name) and t != "kitbench"
        )
    assert _cycles(graph) == []


def test_the_cycle_finder_finds_cycles():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def _private_reach_ins(tree: ast.Module) -> list[str]:
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__"):
            owner = node.value
            if isinstance(owner, ast.Name) and owner.id in ("self", "cls"):
                continue
            if isinstance(owner, ast.Call) and isinstance(owner.func, ast.Name) and owner.func.id == "super":
                continue
            found.append(f"{node.lineno}: {ast.unparse(node)}")
    return found


@pytest.mark.parametrize("root", [PACKAGE, PLUGIN], ids=["kitbench", "plugin"])
def test_no_reaching_into_other_objects_private_members(root):
    found = {str(p.relative_to(root)): _private_reach_ins(ast.parse(p.read_text())) for p in root.rglob("*.py")}
    assert {k: v for k, v in found.items() if v} == {}


def test_the_reach_in_finder_finds_them():
    assert _private_reach_ins(ast.parse("u._cameras\nself._ok\nsuper()._fine()\nenv.unwrapped._task_state(x)")) == [
        "1: u._cameras",
        "4: env.unwrapped._task_state",
    ]


def _code_words(tree: ast.Module) -> list[tuple[int, str]]:
    """Identifiers and string constants that are not docstrings."""
    docstrings = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                docstrings.add(id(first.value))
    words = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docstrings:
            words.append((node.lineno, node.value))
        elif isinstance(node, ast.Name):
            words.append((node.lineno, node.id))
        elif isinstance(node, ast.Attribute):
            words.append((node.lineno, node.attr))
        elif isinstance(node, (ast.FunctionDef, ast.ClassDef, ast.AsyncFunctionDef, ast.alias)):
            words.append((node.lineno, node.name))
    return words


def _task_mentions(root: Path, parts: tuple[str, ...]) -> dict[str, list[str]]:
    found = {}
    for part in parts:
        for path in sorted((root / part).rglob("*.py")) if (root / part).is_dir() else [root / part]:
            hits = [
                f"{line}: {word}" for line, word in _code_words(ast.parse(path.read_text())) if TASK_WORDS.search(word)
            ]
            if hits:
                found[str(path.relative_to(root))] = hits
    return found


def test_shared_code_names_no_task():
    assert _task_mentions(PACKAGE, TASK_FREE) == {}


def test_the_plugin_names_no_task_outside_its_default():
    found = _task_mentions(PLUGIN, ("lerobot_env_kitbench", "gym_kitbench"))
    # the config's default `--env.task` is a value a user sees in --help, as lerobot's own configs have
    assert list(found) == ["lerobot_env_kitbench/config.py"] and len(found["lerobot_env_kitbench/config.py"]) == 1


def test_the_task_word_finder_ignores_docstrings_only():
    tree = ast.parse('"""About the peg."""\ndef f():\n    """the peg"""\n    return u.peg\nx = "AssemblingKits-v1"\n')
    assert sorted(w for _, w in _code_words(tree) if TASK_WORDS.search(w)) == ["AssemblingKits-v1", "peg"]


# -- the shape the code keeps (each a target of the architecture it was rebuilt to) --------------------------------
def _python_files(*roots: Path) -> list[Path]:
    return [p for root in roots for p in sorted(root.rglob("*.py"))]


def test_code_outside_the_env_package_reaches_the_env_through_its_typed_interface():
    """`KitbenchEnv` (kitbench/envs/interface.py) is what the rest of kitbench asks; the two `.unwrapped` left are a
    task's planner (handed the env itself) and the plugin's env (which wraps the bare env in LeRobot's names)."""
    found = [
        f"{p.relative_to(PACKAGE.parent)}:{line}"
        for p in _python_files(PACKAGE, PLUGIN)
        if "envs" not in p.relative_to(PACKAGE.parent).parts[:2]
        for line, word in _code_words(ast.parse(p.read_text()))
        if word == "unwrapped"
    ]
    assert len(found) <= 2, found


def test_the_metadata_files_are_named_by_one_module():
    names = ("kitbench_recording.json", "kitbench_episodes.jsonl")
    found = sorted(
        str(p.relative_to(PACKAGE))
        for p in _python_files(PACKAGE)
        if any(any(n in w for n in names) for _, w in _code_words(ast.parse(p.read_text())) if isinstance(w, str))
    )
    assert found == ["metadata.py"], found


def test_one_episode_loop_steps_the_envs():
    """Recording, conversion, evaluation (one env and batched) and `eval --save-dataset` all run `rollout.run`; the
    one other `.step(` on an env is a conversion's shadow replaying its source."""
    calls = []
    for path in _python_files(PACKAGE):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "step":
                owner = ast.unparse(node.func.value)
                if "env" in owner or "shadow" in owner:
                    calls.append(f"{path.relative_to(PACKAGE)}: {owner}.step")
    assert sorted(calls) == ["recording/convert.py: self.shadow.step", "rollout.py: episode.env.step"], calls


def test_flags_are_derived_from_the_declared_settings():
    """Every flag comes from a declaration (kitbench/config/flags.py); the command line itself is short."""
    calls = {
        str(p.relative_to(PACKAGE)): sum(
            isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute) and n.func.attr == "add_argument"
            for n in ast.walk(ast.parse(p.read_text()))
        )
        for p in _python_files(PACKAGE)
    }
    assert sum(calls.values()) <= 20 and {k for k, v in calls.items() if v} <= {"config/flags.py", "cli.py"}, calls
    assert len((PACKAGE / "cli.py").read_text().splitlines()) <= 250


def test_an_exception_is_written_as_one_line_by_one_helper():
    """`kitbench.errors.one_line`: its type and its message's first line, or the line alone; no other module of the
    package writes its own (a `str(exc).splitlines()`, a `" ".join(str(exc).split())` or a `type(exc).__name__`)."""
    from kitbench.errors import one_line

    assert one_line(ValueError("bad value\nmore")) == "ValueError: bad value"
    assert one_line(OSError("  gone  \n"), typed=False) == "gone" and one_line(RuntimeError()) == "RuntimeError"
    exc = r"str\((e|exc|error)\)"
    by_hand = re.compile(rf"{exc}(\.strip\(\))?\.splitlines\(\)|{exc}\.split\(\)|type\((e|exc|error)\)\.__name__")
    found = {
        str(p.relative_to(PACKAGE))
        for p in _python_files(PACKAGE)
        if p.name != "errors.py" and by_hand.search(p.read_text())
    }
    assert not found, found
