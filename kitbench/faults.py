"""Named fault points, for kill tests: `KITBENCH_FAULT=<point>:<n>` makes the process that reads it kill itself
with SIGKILL (what `kill -9` does: no handler, no flush, no clean-up) the nth time it passes `<point>` (`<point>`
alone: the first time). Wall-clock kills rarely land inside a commit or between two renames; a point reaches
such a moment every time. Unset, a pass costs one comparison.

Only the process that read the variable first counts passes: spawned workers inherit the variable but not the
plan's owner, so a point inside a worker never fires there. Every point is listed in `POINTS`, with the moment
it marks; what a kill there costs is in docs/recording.md ("What a kill costs") and, for `kitbench eval`, in
docs/evaluation.md ("Resuming").
"""

from __future__ import annotations

import os
import signal

from kitbench.errors import KitbenchError

VAR = "KITBENCH_FAULT"
OWNER_VAR = "KITBENCH_FAULT_OWNER"

POINTS = {
    "record.started": "the journal holds the settings, nothing recorded yet",
    "journal.write": "a journal file (an episode, its MCAP log, the settings) written under its temporary name",
    "journal.added": "an episode and its MCAP log durable in the journal, not yet in the open session",
    "writer.frames": "half of an episode's frames handed to LeRobot's episode buffer",
    "writer.saved": "an episode saved into the open session: its data file open, without a footer",
    "session.published": "an episode and its MCAP log link in the open session",
    "commit.finalized": "the session finalized by LeRobot, kitbench's metadata not yet written",
    "commit.metadata": "the session's kitbench metadata written, the card not yet",
    "commit.card": "the session complete, not yet renamed into place",
    "commit.retired": "the dataset renamed aside, the session not yet in its place",
    "commit.swapped": "the session in place, the previous dataset not yet deleted",
    "commit.done": "a commit published, its episodes still in the journal",
    "journal.discard": "a commit's journal entries half deleted",
    "resume.republish": "a resumed run publishing what the journal held",
    "record.finishing": "every episode committed, the journal being deleted",
    "shards.extracting": "a finished shard half unpacked into the journal",
    "shards.merged": "the shards merged beside the dataset, not yet renamed into place",
    "shards.swapped": "the merged dataset in place, the shards still in the journal",
    "merge.aggregated": "kitbench merge: the inputs aggregated, the logs and metadata not yet added",
    "merge.retired": "kitbench merge --overwrite: the old dataset renamed aside, the new one not yet in place",
    "eval.started": "kitbench eval: the journal holds the settings and provenance, nothing scored yet",
    "eval.journaled": "kitbench eval: a job's scores (an episode, or a batch) durable in the journal, the next not "
    "yet taken",
    "eval.scored": "kitbench eval: every episode journaled, no report or dataset written yet",
    "eval.reported": "kitbench eval: the report written without its videos, none filmed yet",
    "eval.filmed": "kitbench eval: a video written, the report not yet listing it",
    "eval.finishing": "kitbench eval: the report complete, the journal being deleted",
}

_plan: tuple[str, int] | None = None
_passes = 0
_read = False


def parse(text: str) -> tuple[str, int]:
    """`<point>` or `<point>:<n>` (n >= 1); a bad value is one line naming it and the valid choices."""
    name, _, count = text.partition(":")
    if name not in POINTS:
        raise KitbenchError(f"{VAR}={text!r}: unknown point {name!r}; valid points: {', '.join(POINTS)}")
    if count and not (count.isdigit() and int(count) >= 1):
        raise KitbenchError(f"{VAR}={text!r}: the pass count must be a whole number >= 1, got {count!r}")
    return name, int(count or 1)


def arm() -> None:
    """Read the variable (once per process; the command line calls this first, so a bad value stops it before
    anything runs). The plan belongs to this process: workers it starts see the owner's pid, not theirs."""
    global _plan, _read
    if _read:
        return
    _read = True
    text = os.environ.get(VAR)
    if not text:
        return
    owner = os.environ.setdefault(OWNER_VAR, str(os.getpid()))
    if owner != str(os.getpid()):
        return
    _plan = parse(text)


def point(name: str) -> None:
    """Pass the fault point `name` (one of `POINTS`)."""
    global _passes
    if not _read:
        arm()
    if _plan is None or _plan[0] != name:
        return
    _passes += 1
    if _passes == _plan[1]:
        os.kill(os.getpid(), signal.SIGKILL)
