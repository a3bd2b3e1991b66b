"""One evaluation episode: the policy acts until the episode ends; only what a report needs is kept.

The task ends an episode at its first success; with `settle_steps` it runs on that many steps more (or to the
time limit), and the episode has two outcomes, as ManiSkill reports them: `success_once` (successful at any step)
and `success_at_end` (successful at the last step). `success` is the suite's headline of the two.

Scoring is hooks on the one rollout loop (`kitbench.rollout`): `EpisodeScore` (nothing is copied per step beyond a
grasp check) and, for a video, `VideoFrames`. A batch of episodes (`evaluate_batch`) steps several envs in lockstep
with one policy call per step for all of them, as `lerobot-eval` does.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from kitbench.envs.grasp import GraspHistory
from kitbench.envs.interface import as_kitbench
from kitbench.evaluation.outcomes import criteria, failure_category, watch_grasp
from kitbench.rollout import Episode, Hook, OneEpisode, SettleAfterSuccess, Step, run


@dataclass
class EpisodeResult:
    seed: int
    success: bool  # the headline: success_at_end when the episode settled after success, else success_once
    length: int  # control steps taken
    steps_to_success: int | None  # control steps until the first successful state
    episode_return: float
    criteria: dict[str, bool]  # at the last step
    failure: str | None  # category, None for a success
    config: dict = field(default_factory=dict)  # the task's episode_config()
    final: dict = field(default_factory=dict)  # the last step's task measurements (errors, tilt, ...)
    physics_error: str | None = None  # what went wrong when the simulation failed (`info["physics_error"]`)
    success_once: bool = False  # successful at some step
    success_at_end: bool = False  # successful at the last step
    initial: dict = field(default_factory=dict)  # the task's measurements after the reset, as `final`'s

    def to_dict(self) -> dict:
        return asdict(self)


def _scalars(info: dict) -> dict:
    out = {}
    for k, v in info.items():
        a = np.asarray(v)
        if a.dtype.kind in "fiub":
            out[k] = bool(a) if a.dtype.kind == "b" else (a.tolist() if a.ndim else float(a))
    return out


class EpisodeScore(Hook):
    """One episode's score, kept as it runs (a hook of the rollout loop): its return, whether and when it
    succeeded, the grasp history the failure categories read, and at the end what it scored."""

    def __init__(self, settle_steps: int = 0):
        self.settle_steps = settle_steps
        self.history = GraspHistory()
        self.total = 0.0
        self.episode: Episode | None = None
        self.initial: dict = {}

    def on_reset(self, episode: Episode) -> None:
        self.episode = episode
        self.initial = _scalars(episode.info)

    def after_step(self, episode: Episode, step: Step) -> None:
        self.total += step.reward
        watch_grasp(episode.env, self.history)

    def result(self) -> EpisodeResult:
        episode = self.episode
        assert episode is not None, "scored after the episode ran"
        env, info = as_kitbench(episode.env), episode.info
        at_end = bool(info["success"])
        first = None if episode.first_success is None else episode.first_success + 1  # steps until it
        headline = at_end if self.settle_steps > 0 else first is not None
        return EpisodeResult(
            seed=episode.seed,
            success=headline,
            length=episode.steps,
            steps_to_success=first,
            episode_return=self.total,
            criteria=criteria(env, info),
            failure=None if headline else failure_category(env, info, self.history),
            config=env.episode_config(),
            final=_scalars(info),
            physics_error=info.get("physics_error"),
            success_once=first is not None,
            success_at_end=at_end,
            initial=self.initial,
        )


class VideoFrames(Hook):
    """A rendered frame per state, the first after the reset, into `frames`."""

    def __init__(self, frames: list):
        self.frames = frames

    def on_reset(self, episode: Episode) -> None:
        self.frames.append(episode.env.render())

    def after_step(self, episode: Episode, step: Step) -> None:
        self.frames.append(episode.env.render())


def score_hooks(settle_steps: int, frames: list | None = None) -> list[Hook]:
    """What scoring an episode adds to the rollout loop (its score first, read with `hooks[0].result()`)."""
    hooks: list[Hook] = [EpisodeScore(settle_steps), SettleAfterSuccess(settle_steps)]
    if frames is not None:
        hooks.append(VideoFrames(frames))
    return hooks


def evaluate_episode(env, policy, seed: int, frames: list | None = None, settle_steps: int = 0) -> EpisodeResult:
    """Run `policy` on `seed` to the end (`settle_steps` after the first success, or the time limit); if `frames` is
    a list, append a rendered frame per state to it."""
    hooks = score_hooks(settle_steps, frames)
    run([as_kitbench(env)], [seed], OneEpisode(policy), lambda _: hooks)
    return hooks[0].result()  # type: ignore[attr-defined]


def evaluate_batch(envs: list, policy, seeds: list[int], settle_steps: int = 0) -> list[EpisodeResult]:
    """Run `policy` (a batch policy) on `seeds`, one env each, in lockstep: one `act_batch` call per control step for
    every episode of the batch. An episode that ends is frozen (its env no longer steps, its last observation still
    fills its row of the policy's batch, its action is dropped) until the batch ends."""
    hooks = [score_hooks(settle_steps) for _ in seeds]
    run([as_kitbench(e) for e in envs], seeds, policy, lambda i: hooks[i])
    return [h[0].result() for h in hooks]  # type: ignore[attr-defined]
