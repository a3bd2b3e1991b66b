"""The evaluation's journal: every finished job (an episode, or a batch) is durable in the report folder before the
next result is taken, so `kitbench eval --resume` after a kill, a SIGTERM or a lost cluster scores only what is
left and writes the report an uninterrupted run writes.

`<out>/journal/`:
- `eval.json`: what a resume must match (policy, checkpoint digests, execution settings, suite, versions) and the
  provenance of the run that started it (the report's), written once, durably (`recording.durable`).
- `results.jsonl`: one line per finished job, in job order: `{"job": i, "seeds": [...], "results": [...]}`, each
  result an `EpisodeResult` as the report lists it. Appended, flushed and synced (fdatasync) per job: a reader sees the
  partial results while the run goes on. A line a power cut left torn, and the lines after it, are dropped and
  scored again.
- `dataset.journal/`: with `--save-dataset`, each episode's frames (the recorder's `EpisodeJournal`), written
  before its line, so a journaled line always has its episode.

A finished evaluation deletes its journal (renamed aside first, so a kill leaves it whole or gone).
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any

from kitbench import faults
from kitbench.errors import KitbenchError
from kitbench.evaluation.episode import EpisodeResult
from kitbench.recording.durable import fsync_dir, write_durably
from kitbench.recording.journal import EpisodeJournal

JOURNAL_DIR = "journal"
SETTINGS_FILE = "eval.json"
RESULTS_FILE = "results.jsonl"
FORMAT = 1


# An appended line needs its data and the file's new size on disk, not its times: fdatasync, a tenth of fsync's
# cost on the machines measured (fsync where there is no fdatasync)
_datasync = getattr(os, "fdatasync", os.fsync)


class EvalJournal:
    def __init__(self, out: Path):
        self.out = Path(out)
        self.root = self.out / JOURNAL_DIR
        self._file: Any = None

    @property
    def results_path(self) -> Path:
        return self.root / RESULTS_FILE

    @property
    def episodes(self) -> EpisodeJournal:
        """The frames of the episodes `--save-dataset` keeps."""
        return EpisodeJournal(self.root / "dataset")

    def exists(self) -> bool:
        return self.root.is_dir()

    def settings(self) -> dict | None:
        """The journal's `eval.json` (None when a kill came before it was written)."""
        path = self.root / SETTINGS_FILE
        if not path.is_file():
            return None
        try:
            data = json.loads(path.read_text())
            if not isinstance(data, dict) or data.get("format") != FORMAT:
                raise ValueError(f"not a format {FORMAT} journal")
        except (OSError, ValueError) as exc:
            raise KitbenchError(
                f"{path} is unreadable ({exc}); pass --overwrite to start the evaluation again"
            ) from None
        return data

    def start(self, settings: dict, provenance: dict) -> None:
        """A new journal (an interrupted one's leftovers replaced)."""
        self.remove()
        self.root.mkdir(parents=True)
        self.results_path.touch()
        data = {"format": FORMAT, "settings": settings, "provenance": provenance}
        write_durably(self.root / SETTINGS_FILE, (json.dumps(data, indent=1) + "\n").encode())
        fsync_dir(self.root)
        fsync_dir(self.out)

    def read(self, jobs: list[tuple[int, ...]]) -> list[list[EpisodeResult]]:
        """The results of the first jobs the journal holds whole, in job order (`jobs`: each job's seeds); a line
        that does not read back, or names other seeds than its job, ends them."""
        if not self.results_path.is_file():
            return []
        done: list[list[EpisodeResult]] = []
        for line in self.results_path.read_bytes().split(b"\n")[:-1]:  # the last piece has no newline: torn
            try:
                entry = json.loads(line)
                results = [EpisodeResult(**r) for r in entry["results"]]
            except (ValueError, TypeError, KeyError):
                break
            i = len(done)
            if i >= len(jobs) or entry.get("job") != i or tuple(r.seed for r in results) != jobs[i]:
                break
            done.append(results)
        return done

    def open(self, kept: int) -> None:
        """Append after the first `kept` lines (anything after them, a torn line, is cut off)."""
        size = 0
        if kept:
            data = self.results_path.read_bytes()
            for _ in range(kept):
                size = data.index(b"\n", size) + 1
        self._file = open(self.results_path, "r+b")  # noqa: SIM115 - held open for the run's appends
        self._file.truncate(size)
        self._file.seek(size)

    def add(self, job: int, results: list[EpisodeResult], episode=None) -> None:
        """Make a finished job durable (its episode's frames first, with `--save-dataset`)."""
        if episode is not None:
            episodes = self.episodes
            if not episodes.exists():
                episodes.root.mkdir()
                fsync_dir(self.root)
            episodes.add(episode)
        entry = {"job": job, "seeds": [r.seed for r in results], "results": [r.to_dict() for r in results]}
        self._file.write(json.dumps(entry).encode() + b"\n")
        self._file.flush()
        _datasync(self._file.fileno())
        faults.point("eval.journaled")

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None

    def remove(self) -> None:
        """Delete the journal: renamed aside first, so that it is whole or gone."""
        self.close()
        aside = self.out / f".{JOURNAL_DIR}.removing"
        if self.root.exists():
            shutil.rmtree(aside, ignore_errors=True)
            os.replace(self.root, aside)
        shutil.rmtree(aside, ignore_errors=True)

    def count(self) -> int:
        """Episodes the journal holds (for messages)."""
        if not self.results_path.is_file():
            return 0
        total = 0
        for line in self.results_path.read_bytes().splitlines():
            try:
                total += len(json.loads(line)["results"])
            except (ValueError, TypeError, KeyError):
                break
        return total
