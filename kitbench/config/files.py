"""Settings files (recording recipes, evaluation suites): TOML, keys at top level or under one table, each key a
declared setting."""

from __future__ import annotations

import tomllib
from collections.abc import Collection
from pathlib import Path

from kitbench.errors import KitbenchError


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


def read_settings(path: str | Path, kind: str, table: str, keys: Collection[str]) -> dict:
    """The settings in the TOML file `path` (at top level or under `[table]`), each key one of `keys` (listed in
    their order, or sorted for a set); every error names the `kind` of file ("recipe", "suite") and its path."""
    path = Path(path)
    where = f"{kind} {path}"
    if not path.is_file():
        raise KitbenchError(f"{where} does not exist")
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise KitbenchError(f"{where}: invalid TOML: {exc}") from exc
    data = settings_table(data, table, keys, where)
    unknown = sorted(set(data) - set(keys))
    if unknown:
        valid = ", ".join(sorted(keys) if isinstance(keys, set | frozenset) else keys)
        raise KitbenchError(f"{where}: unknown key(s) {', '.join(unknown)}; valid keys: {valid}")
    return data
