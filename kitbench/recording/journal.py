"""The episode journal: each finished episode is durable on disk before the recorder moves on.

Publishing episodes into a LeRobot dataset costs a session clone and a `finalize()` (about 1.5 s), so commits
stay periodic (`commit_interval`). Between commits every stored episode is also written to `<out>.journal/`: one
`.npz` file per episode (its frames and metadata, written to a temporary name, fsync'd, then renamed, so a file
under its final name is always whole) and its MCAP log beside it (written the same way, first). After a kill,
`--resume` hands the journaled episodes back to the writer, in seed order, before recording goes on: a kill -9
at any moment loses at most the episode in flight. A commit deletes the journal entries it published.

The journal also keeps the recording's settings (`recording.json`), so a run killed before its first commit,
which leaves no dataset folder at all, can still be resumed and checked against what was asked.
"""

from __future__ import annotations

import io
import json
import os
import shutil
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
from mcap.writer import MCAP0_MAGIC as MCAP_MAGIC  # an MCAP file's first and last 8 bytes

from kitbench import faults
from kitbench.errors import KitbenchError
from kitbench.metadata import RecordingInfo
from kitbench.recording.durable import fsync_dir, write_durably
from kitbench.recording.layout import SHARDS_DIR, journal_root

__all__ = ["SETTINGS_FILE", "SHARDS_DIR", "EpisodeJournal", "journal_root"]
from kitbench.recording.rollout import EpisodeRecord

SETTINGS_FILE = "recording.json"
_META = "__meta__"


class EpisodeJournal:
    """Finished episodes not yet published in the dataset, one file each, named by seed."""

    def __init__(self, out: Path):
        self.root = journal_root(out)

    def exists(self) -> bool:
        return self.root.is_dir()

    def settings(self) -> RecordingInfo | None:
        """The settings of the recording the journal belongs to (None when there is no journal)."""
        path = self.root / SETTINGS_FILE
        if not path.is_file():
            return None
        try:
            data = json.loads(path.read_text())
            if not isinstance(data, dict):
                raise ValueError("not a JSON object")
            return RecordingInfo.from_json(data)
        except (OSError, ValueError, TypeError, KitbenchError) as exc:
            raise KitbenchError(
                f"{path} is unreadable ({exc}); delete {self.root} to record its unpublished episodes again"
            ) from None

    def start(self, info: RecordingInfo) -> None:
        """Create the journal for a recording with settings `info` (kept if it exists: a resumed recording)."""
        self.root.mkdir(parents=True, exist_ok=True)
        if not (self.root / SETTINGS_FILE).is_file():
            write_durably(self.root / SETTINGS_FILE, (json.dumps(info.to_json(), indent=2) + "\n").encode())
            fsync_dir(self.root.parent)

    def _path(self, seed: int, suffix: str) -> Path:
        return self.root / f"seed-{seed:010d}{suffix}"

    def add(self, episode: EpisodeRecord, mcap: bytes | None = None) -> Path | None:
        """Make `episode` durable, with its MCAP log's bytes beside it; returns the log's path in the journal."""
        keys = list(episode.frames[0]) if episode.frames else []
        arrays = {k: np.stack([f[k] for f in episode.frames]) for k in keys}
        meta = {
            "seed": episode.seed,
            "task": episode.task,
            "success": episode.success,
            "first_success": episode.first_success,
            "config": episode.config,
            "physics_error": episode.physics_error,
            "teleop": episode.teleop,
            "keys": keys,
        }
        payload: dict[str, Any] = {**arrays, _META: np.array(json.dumps(meta))}
        buffer = io.BytesIO()
        np.savez(buffer, **payload)  # uncompressed: fast, and the file lives only until the next commit
        log = None
        if mcap is not None:
            log = self._path(episode.seed, ".mcap")
            write_durably(log, mcap)  # before the episode: an episode file under its name has its log
        write_durably(self._path(episode.seed, ".npz"), buffer.getvalue())
        fsync_dir(self.root)
        return log

    def seeds(self) -> list[int]:
        """Seeds of the journaled episodes, in order (only whole files count: a partial one was in flight)."""
        return sorted(int(p.stem[len("seed-") :]) for p in self.root.glob("seed-*.npz"))

    def check(self) -> tuple[list[int], str | None]:
        """The journaled seeds that read back whole, in order, up to the first that does not (damaged on disk:
        a kill leaves no such file). That one and those after it are deleted, so that they are recorded again
        in seed order; the second value names it and why (None when every entry is whole)."""
        seeds = self.seeds()
        for i, seed in enumerate(seeds):
            problem = self._damage(seed)
            if problem is not None:
                self.discard(seeds[i:])
                again = f"seed {seed}" if i == len(seeds) - 1 else f"seeds {seed}-{seeds[-1]}"
                return seeds[:i], f"journal entry {problem}: {again} recorded again"
        return seeds, None

    def _damage(self, seed: int) -> str | None:
        """What is wrong with a journaled episode's files, or None: the archive's checksums and its metadata,
        and its MCAP log's closing magic bytes."""
        path = self._path(seed, ".npz")
        try:
            with zipfile.ZipFile(path) as archive:
                bad = archive.testzip()
                if bad is not None:
                    return f"{path} is damaged ({bad} fails its checksum)"
            with np.load(path) as data:
                meta = json.loads(str(data[_META]))
                if meta.get("seed") != seed or not all(k in data for k in meta["keys"]):
                    return f"{path} does not hold the episode its name says"
        except (OSError, ValueError, KeyError, TypeError, zipfile.BadZipFile) as exc:
            return f"{path} is unreadable ({exc})"
        log = self._path(seed, ".mcap")
        if log.exists():
            with open(log, "rb") as f:
                f.seek(0, os.SEEK_END)
                f.seek(max(f.tell() - len(MCAP_MAGIC), 0))
                if f.read() != MCAP_MAGIC:
                    return f"{log} is truncated (no closing MCAP magic)"
        return None

    def load(self, seed: int) -> tuple[EpisodeRecord, Path | None]:
        """A journaled episode as the recorder produced it, and its MCAP log if it has one."""
        with np.load(self._path(seed, ".npz")) as data:
            meta = json.loads(str(data[_META]))
            arrays = {k: data[k] for k in meta["keys"]}
        length = len(next(iter(arrays.values()))) if arrays else 0
        frames = [{k: v[i] for k, v in arrays.items()} for i in range(length)]
        episode = EpisodeRecord(
            seed=meta["seed"],
            task=meta["task"],
            frames=frames,
            success=meta["success"],
            first_success=meta["first_success"],
            config=meta["config"],
            physics_error=meta["physics_error"],
            teleop=meta.get("teleop"),
        )
        mcap = self._path(seed, ".mcap")
        return episode, (mcap if mcap.exists() else None)

    def discard(self, seeds) -> None:
        """Forget episodes once they are published."""
        for seed in seeds:
            for suffix in (".npz", ".mcap"):
                self._path(seed, suffix).unlink(missing_ok=True)
            faults.point("journal.discard")

    def remove(self) -> None:
        """Delete the whole journal (the recording is complete and committed, or being replaced)."""
        shutil.rmtree(self.root, ignore_errors=True)
