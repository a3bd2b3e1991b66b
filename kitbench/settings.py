"""Checks shared by kitbench's settings files and flags (recording recipes, evaluation suites): TOML tables and
seeds."""

from __future__ import annotations

from kitbench.errors import KitbenchError


def is_seed(value) -> bool:
    # gymnasium refuses negative seeds deep inside `reset`; bool is an int subclass but never meant as a seed
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def check_seed(seed) -> None:
    """Refuse a first seed gymnasium would refuse, before anything runs."""
    if not is_seed(seed):
        raise KitbenchError(f"seed must be a non-negative integer, got {seed!r}")


def settings_table(data: dict, table: str, keys, where: str) -> dict:
    """The settings of a TOML file that holds them at top level or under `[table]`. A mistyped table name would
    otherwise surface as an unknown key, or the whole table be read as top-level keys, so name it."""
    tables = sorted(k for k, v in data.items() if isinstance(v, dict) and k != table and k not in keys)
    if tables:
        names = ", ".join(f"[{t}]" for t in tables)
        raise KitbenchError(
            f"{where}: unknown table {names}; the valid table is [{table}] (or put the keys at the top level)"
        )
    if table not in data:
        return data
    if not isinstance(data[table], dict):
        raise KitbenchError(f"{where}: {table} must be a table ([{table}]), got {data[table]!r}")
    stray = sorted(set(data) - {table})
    if stray:  # keys above the table header, which would otherwise be ignored
        raise KitbenchError(f"{where}: key(s) {', '.join(stray)} outside the [{table}] table; move them into it")
    return data[table]
