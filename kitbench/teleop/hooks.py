"""The rollout hook of a teleoperated episode (`TeleopHook`): each step is released on the control rate's
wall-clock deadline (`Pacer`) just before the device is read, the episode keys can end the episode after any step
(`Control`: next, re-record, stop), and the live view shows each new state with the action that led to it."""

from __future__ import annotations

import math
import sys
from collections.abc import Callable

from kitbench.envs.interface import as_kitbench
from kitbench.rollout import Control, Episode, Hook, Step
from kitbench.teleop.keys import BUTTON, EpisodeKeys
from kitbench.teleop.pacing import Pacer
from kitbench.teleop.view import View

# what a line says of how an episode ended at a person's request
ENDED = {Control.NEXT: "ended early (next)", Control.RERECORD: "discarded (re-record)", Control.STOP: "stopped"}


def ended_by(key: str) -> dict[str, str]:
    """How an episode a person ended says so: the key (`right`, `esc`, ...) or the device's button event."""
    if key.startswith(BUTTON):
        return {"ended": "button", "button": key[len(BUTTON) :]}
    return {"ended": "key", "key": key}


def say(message: str) -> None:
    print(f"teleop: {message}", file=sys.stderr, flush=True)


class TeleopHook(Hook):
    """Paces (with `pacer()`, the policy's, made at its reset; None: as fast as it goes), listens and shows one
    episode, and ends it after `max_seconds` of control steps (None: never; the task's step limit is lifted while a
    person drives); `clipped()` counts the device's values clipped so far, `limited()` the episode's steps held to
    the joint speeds. The episode keeps how it ended and those counts (`Episode.teleop`)."""

    def __init__(self, pacer: Callable[[], Pacer | None], keys: EpisodeKeys, view: View, clipped: Callable[[], int],
                 limited: Callable[[], int], max_seconds: float | None = None):  # fmt: skip
        self.pacer_of, self.keys, self.view, self.clipped, self.limited = pacer, keys, view, clipped, limited
        self.max_seconds = max_seconds
        self.max_steps: int | None = None
        self.pacer: Pacer | None = None
        self.clipped_before = 0
        self.ended: dict[str, str] = {}

    def on_reset(self, episode: Episode) -> None:
        self.clipped_before = self.clipped()
        self.ended = {}
        if self.max_seconds is not None:  # the steps it allows at the env's control rate
            period = as_kitbench(episode.env).control_timestep
            self.max_steps = max(1, math.ceil(self.max_seconds / period - 1e-9))
        self.pacer = self.pacer_of()
        if self.pacer is not None:
            self.pacer.restart()
        self.view.show(as_kitbench(episode.env), episode.obs, None)

    def before_act(self, episode: Episode) -> None:
        if self.pacer is not None:
            self.pacer.wait()

    def end(self, episode: Episode, terminated: bool) -> bool:
        closed = self.view.closed
        control = Control.STOP if closed else self.keys.take()
        if control is not None:
            episode.control = control
            self.ended = {"ended": "window"} if closed else ended_by(self.keys.last_key or "?")
            return True
        if terminated:
            return True
        if self.max_steps is not None and episode.steps >= self.max_steps:
            self.ended = {"ended": "limit"}
            return True
        return False

    def after_step(self, episode: Episode, step: Step) -> None:
        self.view.show(as_kitbench(episode.env), episode.obs, step.executed)

    def on_end(self, episode: Episode) -> None:
        if not self.ended:  # success (after the settle steps), the simulation failing, or an env's own step limit
            failed = "physics error" if episode.info.get("physics_error") else "limit"
            self.ended = {"ended": "success" if episode.success else failed}
        episode.teleop = {
            **self.ended,
            "clipped": self.clipped() - self.clipped_before,
            "rate_limited": self.limited(),
        }
        outcome = f"success at step {episode.first_success + 1}" if episode.first_success is not None else "no success"
        ended = "" if episode.control is None else f", {ENDED[episode.control]}"
        if self.ended["ended"] == "limit":
            ended = f", ended at the {self.max_steps}-step limit (max_seconds)"
        clipped = self.clipped() - self.clipped_before
        clips = f", {clipped} values clipped to the joint limits" if clipped else ""
        limited = self.limited()
        slowed = f", {limited} steps held to the follower's joint speeds" if limited else ""
        say(f"seed {episode.seed}: {outcome}, {episode.steps} steps{ended}{clips}{slowed}")
