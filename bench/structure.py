"""How a command's work travels through kitbench's modules: `python bench/structure.py [--root CHECKOUT]`.

For `kitbench record` (2 LiftPegUpright state episodes by the expert, one worker) and `kitbench eval` (the expert
on the standard suite's first 2 seeds), run in one process under `sys.setprofile`, it prints:
- the kitbench modules whose functions ran;
- the calls that climb back up: a function of module A calling one of module B where B imports A, directly or
  through others (module-level and in-function imports alike; the package has no import cycles, so "above" is
  well defined). Such a call reaches a higher layer through an object or a function handed down; each distinct
  (A, B) pair counts once. A call of a method declared on a class A knows (in A or a module A imports, for type
  checking too): a base
  class of the callee's or a `typing.Protocol` (the typed hooks of `TabletopEnv`, the planners, `rollout.py`), is
  counted apart, as a hook; a pair is a climb if any of its calls is not. Calls made while a module is imported
  are left out.

`--root` measures another checkout with the same method (its `kitbench/` first on the path), so a change's before
and after come from one tool. Everything is written into a temporary folder.
"""

from __future__ import annotations

import argparse
import ast
import inspect
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
COMMANDS = {
    "record": ["record", "--task", "LiftPegUpright-v1", "--obs-mode", "state", "--episodes", "2", "--workers", "1"],
    "eval": [
        *("eval", "--policy", "expert", "--suite", "eval/suites/lift_peg_upright.toml"),
        *("--episodes", "2", "--workers", "1"),
    ],
}


def module_imports(package: Path, typing_only: bool = False) -> dict[str, set[str]]:
    """Each kitbench module's kitbench imports (module level and inside functions; those under TYPE_CHECKING too
    with `typing_only`: the classes a module knows by type, not the ones it runs)."""
    paths = {p: ".".join(p.relative_to(package.parent).with_suffix("").parts) for p in package.rglob("*.py")}
    names = {n.removesuffix(".__init__") for n in paths.values()}
    graph: dict[str, set[str]] = {}
    for path, dotted in paths.items():
        name = dotted.removesuffix(".__init__")
        tree = ast.parse(path.read_text())
        skip = {
            id(n)
            for node in ast.walk(tree)
            if not typing_only and isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test)
            for child in node.body
            for n in ast.walk(child)
        }
        here = name if path.name == "__init__.py" else name.rpartition(".")[0]
        found = set()
        for node in ast.walk(tree):
            if id(node) in skip:
                continue
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    parts = here.split(".")[: len(here.split(".")) - node.level + 1]
                    base = ".".join(parts + ([base] if base else []))
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in names else base for a in node.names]
            for target in targets:
                while target and target not in names:
                    target = target.rpartition(".")[0]
                if target and target != name:
                    found.add(target)
        graph[name] = found
    return graph


def below(graph: dict[str, set[str]]) -> dict[str, set[str]]:
    """Each module's transitive imports."""
    memo: dict[str, set[str]] = {}

    def visit(name: str, seen: tuple[str, ...] = ()) -> set[str]:
        if name not in memo:
            out: set[str] = set()
            for child in graph.get(name, ()):
                if child not in seen:
                    out |= {child} | visit(child, (*seen, name))
            memo[name] = out
        return memo[name]

    for name in graph:
        visit(name)
    return memo


def trace(command: list[str], out: Path) -> None:
    """Run `kitbench <command>` here under a profiler; write the (caller module, callee module) pairs seen."""
    import threading

    import kitbench
    from kitbench.cli import main

    pairs: dict[tuple[str, str], bool] = {}
    known_below = below(module_imports(Path(kitbench.__file__).parent, typing_only=True))

    def importing(frame) -> bool:
        """Whether the call runs while a module is being imported (a decorator, a class body): not the command."""
        while frame is not None:
            if frame.f_code.co_name == "<module>" and frame.f_globals.get("__name__") != "__main__":
                return True
            frame = frame.f_back
        return False

    def hook(frame, caller: str) -> bool:
        """Whether the callee is a method declared on a class the caller knows (its own module's or one it
        imports): a base class the callee's class derives from, or a `typing.Protocol` (a typed hook)."""
        owner = frame.f_locals.get("self", frame.f_locals.get("cls"))
        if owner is None:
            return False
        known = {caller} | known_below.get(caller, set())
        mro = owner.__mro__ if isinstance(owner, type) else type(owner).__mro__
        name = frame.f_code.co_name
        if any(c.__module__ in known and name in vars(c) for c in mro):
            return True
        return any(
            isinstance(c, type) and getattr(c, "_is_protocol", False) and c.__module__ in known and name in vars(c)
            for module in known
            if module in sys.modules
            for c in vars(sys.modules[module]).values()
        )

    def profile(frame, event, arg):
        # a generator runs when its consumer iterates it: the call that made it is the one that counts
        if event != "call" or frame.f_back is None or frame.f_code.co_flags & inspect.CO_GENERATOR:
            return
        callee = frame.f_globals.get("__name__", "")
        caller = frame.f_back.f_globals.get("__name__", "")
        if not (callee.startswith("kitbench") and caller.startswith("kitbench") and callee != caller):
            return
        if (caller, callee) in pairs and not pairs[(caller, callee)]:
            return  # seen, and not only as a hook
        if importing(frame):
            return
        pairs[(caller, callee)] = pairs.get((caller, callee), True) and hook(frame, caller)

    sys.setprofile(profile)
    threading.setprofile(profile)
    try:
        code = main(command)
    except SystemExit as exc:
        code = exc.code
    finally:
        sys.setprofile(None)
        threading.setprofile(None)  # type: ignore[arg-type]
    if code not in (0, None):
        raise SystemExit(f"kitbench {' '.join(command)} exited with {code}")
    out.write_text(json.dumps(sorted([a, b, h] for (a, b), h in pairs.items())))


def measure(root: Path, name: str, work: Path) -> dict:
    pairs_file = work / f"{name}.json"
    command = [*COMMANDS[name], "--out", str(work / name)]
    env = {**os.environ, "PYTHONPATH": str(root), "HF_HUB_OFFLINE": "1"}
    args = [sys.executable, __file__, "--trace", json.dumps(command), str(pairs_file)]
    run = subprocess.run(args, cwd=root, env=env, capture_output=True, text=True, check=False)
    if run.returncode != 0:
        raise SystemExit(f"structure: kitbench {' '.join(command)} failed in {root}:\n{run.stderr[-3000:]}")
    pairs = json.loads(pairs_file.read_text())
    above = below(module_imports(root / "kitbench"))
    up = [(a, b, hook) for a, b, hook in pairs if a in above.get(b, set())]
    return {
        "modules": sorted({m for a, b, _ in pairs for m in (a, b)}),
        "climbs": sorted((a, b) for a, b, hook in up if not hook),
        "hooks": sorted((a, b) for a, b, hook in up if hook),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=ROOT, help="the checkout to measure (default: this one)")
    parser.add_argument("--commands", default="record,eval", help="of: " + ", ".join(COMMANDS))
    parser.add_argument("--verbose", action="store_true", help="list the modules and each climb")
    parser.add_argument("--trace", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.trace:
        trace(json.loads(args.trace[0]), Path(args.trace[1]))
        return
    names = args.commands.split(",")
    for name in names:
        if name not in COMMANDS:
            parser.error(f"--commands: {name!r} is not a command here; valid choices: {', '.join(COMMANDS)}")
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            found = measure(args.root.resolve(), name, Path(tmp))
            print(
                f"kitbench {name}: {len(found['modules'])} modules, {len(found['climbs'])} climbs back up, "
                f"{len(found['hooks'])} more through typed hooks"
            )
            if args.verbose:
                print("  modules: " + ", ".join(m.removeprefix("kitbench.") for m in found["modules"]))
                for kind in ("climbs", "hooks"):
                    for a, b in found[kind]:
                        print(f"  {kind[:-1]}: {a.removeprefix('kitbench.')} -> {b.removeprefix('kitbench.')}")


if __name__ == "__main__":
    main()
