"""Where a recording's parts live: the dataset at `<out>`, and beside it the session a commit is building
(`<out>.session`), the previous dataset while a commit swaps them (`<out>.retired`), and the journal of episodes not
yet committed (`<out>.journal`, whole shards of a sharded recording under its `shards/`)."""

from __future__ import annotations

from pathlib import Path

SESSION_SUFFIX = ".session"
RETIRED_SUFFIX = ".retired"
JOURNAL_SUFFIX = ".journal"
SHARDS_DIR = "shards"


def beside(out: Path, suffix: str) -> Path:
    """`<out><suffix>`: a sibling, so publishing `out` never touches it."""
    out = Path(out)
    return out.with_name(out.name + suffix)


def journal_root(out: Path) -> Path:
    """The journal folder of the dataset folder `out`."""
    return beside(out, JOURNAL_SUFFIX)
