"""The one episode loop: a policy acts in one env, or in several envs in lockstep (one policy call a step for
all of them), until every episode ends. Recording, conversion, evaluation and `eval --save-dataset` all run it,
each adding what it keeps through small hooks (`Hook`): dataset frames and MCAP logs (`recording.rollout`),
expert labels and action noise (`recording.rollout`), scores and video frames (`evaluation.episode`), and the
ending after success (`SettleAfterSuccess`).

Each step, for every episode still running: the hooks see the state (`before_act`), the policy acts (`act_batch`
over every episode, finished ones still filling their rows so a batching policy's queues stay aligned), the action
is clipped to the action box (the env clips the same way; a dataset stores what was applied), the hooks may change
what the robot executes (`executed`: noise) and see it (`on_action`), the env steps, and the hooks see the outcome
(`after_step`) and may extend the episode (`end`). Episodes are stepped in order, so a batch's episodes are the
ones each would be alone.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from enum import Enum
from typing import Any

import numpy as np

from kitbench.config.checks import non_negative_int
from kitbench.config.declare import setting


@dataclass
class SettleSettings:
    # Steps an episode runs on after its first success (the task itself ends it there), the policy holding or
    # finishing the task; scored, above 0 makes success_at_end the headline instead of success_once.
    settle_steps: int = setting(0, check=non_negative_int)


class Control(Enum):
    """What a person at the controls asked of the episode in flight, with lerobot-record's keys."""

    NEXT = "next"  # right arrow: end it now, kept as any episode
    RERECORD = "rerecord"  # left arrow: discard it and run its seed again
    STOP = "stop"  # escape: end it now, kept as any episode, and stop the recording


@dataclass
class Step:
    """What one control step did."""

    action: np.ndarray  # the policy's, clipped to the action box
    executed: np.ndarray  # what the robot got (the action, or a hook's change of it)
    reward: float
    terminated: bool  # the episode ends here (the task's end, or a hook's)
    truncated: bool
    info: dict


@dataclass
class Episode:
    """One episode as it runs."""

    env: Any
    seed: int
    hooks: list[Hook] = field(default_factory=list)
    obs: Any = None
    info: dict = field(default_factory=dict)
    steps: int = 0  # control steps taken
    first_success: int | None = None  # the index of the step whose outcome was the first success
    done: bool = False
    control: Control | None = None  # set by the hook that ended the episode at a person's request
    teleop: dict[str, Any] | None = None  # a person's episode: how it ended, values clipped, steps rate-limited

    @property
    def success(self) -> bool:
        return self.first_success is not None


class Hook:
    """Watches one episode and may change what its robot executes or when it ends; every method is optional."""

    def on_reset(self, episode: Episode) -> None:
        """The env was reset (`episode.obs`, `episode.info`)."""

    def before_act(self, episode: Episode) -> None:
        """The state the policy is about to act on."""

    def executed(self, episode: Episode, action: np.ndarray) -> np.ndarray:
        """What the robot executes instead of `action` (the policy's, clipped, or an earlier hook's change)."""
        return action

    def on_action(self, episode: Episode, action: np.ndarray, executed: np.ndarray) -> None:
        """The step about to be taken."""

    def end(self, episode: Episode, terminated: bool) -> bool:
        """Whether the episode ends at this step (`terminated`: the task's say, or an earlier hook's)."""
        return terminated

    def after_step(self, episode: Episode, step: Step) -> None:
        """The step's outcome; `episode` already holds the new observation."""

    def on_end(self, episode: Episode) -> None:
        """The episode is over."""


class SettleAfterSuccess(Hook):
    """The task ends an episode at its first success; this runs it `steps` steps more (or to the time limit),
    whatever the task's state by then."""

    def __init__(self, steps: int):
        self.steps = steps

    def end(self, episode: Episode, terminated: bool) -> bool:
        if episode.first_success is None:
            return terminated
        return episode.steps - 1 - episode.first_success >= self.steps


class OneEpisode:
    """A policy that acts on one env at a time, run as a batch of one (the same calls it gets alone)."""

    def __init__(self, policy):
        self.policy = policy

    def reset_batch(self, envs: list, seeds: list[int], obs: list, infos: list[dict]) -> None:
        (env,), (seed,), (o,), (info,) = envs, seeds, obs, infos
        self.policy.reset(env, seed, o, info)

    def act_batch(self, obs: list, active: list[bool]) -> list:
        return [self.policy.act(obs[0]) if active[0] else None]


def clipped(env, action) -> np.ndarray:
    """The action as the env applies it: float32, within the action box (left as it is when its shape is wrong,
    for the env's own one-line error)."""
    space = env.action_space
    a = np.asarray(action, dtype=np.float32)
    return np.clip(a, space.low, space.high) if a.shape == space.shape else a


def run(
    envs: Sequence,
    seeds: Sequence[int],
    policy,
    hooks: Callable[[int], list[Hook]] | None = None,
) -> list[Episode]:
    """Run `policy` (a batch policy: `reset_batch` and `act_batch`; wrap a one-env policy in `OneEpisode`) on
    `seeds`, one env each, to the end; `hooks(i)`: the hooks of episode i."""
    envs = list(envs)[: len(seeds)]
    episodes = [
        Episode(env, seed, hooks(i) if hooks else []) for i, (env, seed) in enumerate(zip(envs, seeds, strict=True))
    ]
    for episode in episodes:
        episode.obs, episode.info = episode.env.reset(seed=episode.seed)
    policy.reset_batch(envs, list(seeds), [e.obs for e in episodes], [e.info for e in episodes])
    for episode in episodes:
        for hook in episode.hooks:
            hook.on_reset(episode)
    while not all(e.done for e in episodes):
        for episode in episodes:
            if not episode.done:
                for hook in episode.hooks:
                    hook.before_act(episode)
        actions = policy.act_batch([e.obs for e in episodes], [not e.done for e in episodes])
        for episode, raw in zip(episodes, actions, strict=True):
            if not episode.done:
                _step(episode, clipped(episode.env, raw))
    for episode in episodes:
        for hook in episode.hooks:
            hook.on_end(episode)
    return episodes


def _step(episode: Episode, action: np.ndarray) -> None:
    executed = action
    for hook in episode.hooks:
        executed = hook.executed(episode, executed)
    for hook in episode.hooks:
        hook.on_action(episode, action, executed)
    obs, reward, terminated, truncated, info = episode.env.step(executed)
    if info["success"] and episode.first_success is None:
        episode.first_success = episode.steps
    episode.steps += 1
    for hook in episode.hooks:
        terminated = hook.end(episode, terminated)
    episode.obs, episode.info = obs, info
    episode.done = bool(terminated or truncated)
    step = Step(action, executed, float(reward), bool(terminated), bool(truncated), info)
    for hook in episode.hooks:
        hook.after_step(episode, step)
