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


def last_commit(root: Path) -> Path | None:
    """The folder holding the last commit of the dataset at `root`, as `recover` will leave it: `root` itself, or,
    after a kill between a commit's two renames, its session (finalized before the first rename) or the folder set
    aside. None when nothing was ever committed: a session beside no dataset is one a kill left unfinished (its
    data file may have no footer yet) and is never read."""
    root = Path(root)
    if root.exists():
        return root
    session, retired = beside(root, SESSION_SUFFIX), beside(root, RETIRED_SUFFIX)
    if retired.is_dir():
        return session if session.is_dir() else retired
    return None
