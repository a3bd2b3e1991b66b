"""lerobot-record's episode boundaries, told to the simulated robot.

lerobot 0.6.1's `lerobot-record` asks a robot for nothing at its episode boundaries: `record()` runs
`record_loop(dataset=...)` for each episode, then `record_loop(dataset=None)` for its reset phase (skipped after the
last episode), then `dataset.save_episode()`, or `dataset.clear_episode_buffer()` when the episode is re-recorded
(`events["rerecord_episode"]`, the left arrow, pressed during the episode or its reset phase); inside a loop the robot
only sees `get_observation` and `send_action`. There is no hook for either, so when a `KitbenchSO101` connects in a
process where `lerobot.scripts.lerobot_record` is loaded, its module-level `record_loop` (which `record()` looks up
on each call) is wrapped once: before an episode's loop the robot is told which dataset episode it starts (so the
scene is reset on that episode's seed, and a re-recorded episode meets its seed again), after it how the episode
ended, and before a reset phase which episode comes next. Loops of any other robot pass through untouched.
"""

from __future__ import annotations

import functools
import sys
import time
from pathlib import Path
from typing import Any, Protocol, cast

RECORD_MODULE = "lerobot.scripts.lerobot_record"
WRAPPED = "_kitbench_episodes"  # marks the wrapper, so that it is installed once


class Episodic(Protocol):
    """What the wrapper tells the robot."""

    def begin_episode(self, index: int, root: Path, saved: Any) -> None:
        """Dataset episode `index` starts (`root`: the dataset's folder; `saved()`: episodes saved so far)."""

    def end_episode(self, ended: dict[str, str]) -> None:
        """The episode's loop ended, as `ended` says (`{"ended": "limit"}`: its time ran out; `{"ended": "key",
        "key": "right" | "left" | "esc"}`); saved or re-recorded: told by the next `begin_episode` or `disconnect`."""

    def begin_reset(self, rerecord: bool) -> None:
        """lerobot's reset phase starts; `rerecord`: the episode that ended is recorded again."""


def install(kind: type) -> bool:
    """Wrap lerobot-record's `record_loop` for robots of `kind` (once); False where lerobot-record is not running
    in this process."""
    module = sys.modules.get(RECORD_MODULE)
    if module is None:
        return False
    loop = vars(module)["record_loop"]
    if not getattr(loop, WRAPPED, False):
        setattr(module, "record_loop", _episodic(loop, kind))  # noqa: B010  (a module attribute mypy cannot see)
    return True


def _episodic(loop, kind: type):
    @functools.wraps(loop)
    def record_loop(*args, **kwargs):
        robot = kwargs.get("robot", args[0] if args else None)
        if not isinstance(robot, kind):
            return loop(*args, **kwargs)
        robot = cast(Episodic, robot)
        dataset = kwargs.get("dataset")
        events = kwargs.get("events", args[1] if len(args) > 1 else {})
        if dataset is None:
            robot.begin_reset(rerecord=bool(events.get("rerecord_episode")))
            return loop(*args, **kwargs)
        robot.begin_episode(dataset.num_episodes, Path(dataset.root), lambda: dataset.num_episodes)
        start = time.perf_counter()
        try:
            return loop(*args, **kwargs)
        finally:
            robot.end_episode(_ended(events, time.perf_counter() - start, kwargs.get("control_time_s")))

    setattr(record_loop, WRAPPED, True)
    return record_loop


def _ended(events: dict, seconds: float, limit: float | None) -> dict[str, str]:
    """How an episode's loop ended: the keys leave their flags set (but the right arrow's, which the loop clears
    as it leaves early), else it ended at its time."""
    if events.get("stop_recording"):
        return {"ended": "key", "key": "esc"}
    if events.get("rerecord_episode"):
        return {"ended": "key", "key": "left"}
    if limit is not None and seconds < limit:
        return {"ended": "key", "key": "right"}
    return {"ended": "limit"}
