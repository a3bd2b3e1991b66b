"""The rollout hook of a teleoperated episode (`TeleopHook`): each step is released on the control rate's
wall-clock deadline (`Pacer`) just before the device is read, the episode keys can end the episode after any step
(`Control`: next, re-record, stop), and the live view shows each new state with the action that led to it."""

from __future__ import annotations

import sys
from collections.abc import Callable

from kitbench.envs.interface import as_kitbench
from kitbench.rollout import Control, Episode, Hook, Step
from kitbench.teleop.keys import EpisodeKeys
from kitbench.teleop.pacing import Pacer
from kitbench.teleop.view import View

# what a line says of how an episode ended at a person's request
ENDED = {Control.NEXT: "ended early (next)", Control.RERECORD: "discarded (re-record)", Control.STOP: "stopped"}


def say(message: str) -> None:
    print(f"teleop: {message}", file=sys.stderr, flush=True)


class TeleopHook(Hook):
    """Paces (with `pacer()`, the policy's, made at its reset; None: as fast as it goes), listens and shows one
    episode; `clipped()` counts the device's values clipped so far (its line at the episode's end says how many this
    episode had)."""

    def __init__(self, pacer: Callable[[], Pacer | None], keys: EpisodeKeys, view: View, clipped: Callable[[], int],
                 limited: Callable[[], int]):  # fmt: skip
        self.pacer_of, self.keys, self.view, self.clipped, self.limited = pacer, keys, view, clipped, limited
        self.pacer: Pacer | None = None
        self.clipped_before = 0

    def on_reset(self, episode: Episode) -> None:
        self.clipped_before = self.clipped()
        self.pacer = self.pacer_of()
        if self.pacer is not None:
            self.pacer.restart()
        self.view.show(as_kitbench(episode.env), episode.obs, None)

    def before_act(self, episode: Episode) -> None:
        if self.pacer is not None:
            self.pacer.wait()

    def end(self, episode: Episode, terminated: bool) -> bool:
        control = Control.STOP if self.view.closed else self.keys.take()
        if control is None:
            return terminated
        episode.control = control
        return True

    def after_step(self, episode: Episode, step: Step) -> None:
        self.view.show(as_kitbench(episode.env), episode.obs, step.executed)

    def on_end(self, episode: Episode) -> None:
        outcome = f"success at step {episode.first_success + 1}" if episode.first_success is not None else "no success"
        ended = "" if episode.control is None else f", {ENDED[episode.control]}"
        clipped = self.clipped() - self.clipped_before
        clips = f", {clipped} values clipped to the joint limits" if clipped else ""
        limited = self.limited()
        slowed = f", {limited} steps held to the follower's joint speeds" if limited else ""
        say(f"seed {episode.seed}: {outcome}, {episode.steps} steps{ended}{clips}{slowed}")
