"""Writes that survive a power cut, not only a kill: a file is fsync'd before the rename that publishes it, and
the folder holding the new name after. (A kill -9 never loses what the process wrote; a power cut loses what the
kernel had not written back, and may then show a renamed file empty or cut short.)"""

from __future__ import annotations

import os
from pathlib import Path

from kitbench import faults


def fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_durably(path: Path, data: bytes) -> None:
    """`data` under `path`, whole or not at all (a temporary name, fsync'd, then renamed)."""
    partial = path.with_name(f".{path.name}.partial")
    with open(partial, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    faults.point("journal.write")
    os.replace(partial, path)


def fsync_new(root: Path) -> None:
    """fsync every file under `root` that has one name only, and every folder: what a session wrote itself (the
    files it hard-linked from the dataset it extends were made durable by the commit that published them)."""
    for folder, _, files in os.walk(root):
        for name in files:
            path = os.path.join(folder, name)
            if os.stat(path).st_nlink == 1:
                fd = os.open(path, os.O_RDONLY)
                try:
                    os.fsync(fd)
                finally:
                    os.close(fd)
        fsync_dir(Path(folder))
