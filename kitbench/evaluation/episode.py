"""One evaluation episode: the policy acts until the episode ends; only what a report needs is kept.

The task ends an episode at its first success; with `settle_steps` it runs on that many steps more (or to the
time limit), and the episode has two outcomes, as ManiSkill reports them: `success_once` (successful at any step)
and `success_at_end` (successful at the last step). `success` is the suite's headline of the two.

Nothing is copied per step beyond a grasp check (and, for a video, the rendered frame), so scoring runs at the
speed of the simulator and the policy. A batch of episodes (`evaluate_batch`) steps several envs in lockstep with
one policy call per step for all of them, as `lerobot-eval` does.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from kitbench.envs.grasp import GraspHistory
from kitbench.evaluation.outcomes import criteria, failure_category, watch_grasp


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

    def to_dict(self) -> dict:
        return asdict(self)


def _scalars(info: dict) -> dict:
    out = {}
    for k, v in info.items():
        a = np.asarray(v)
        if a.dtype.kind in "fiub":
            out[k] = bool(a) if a.dtype.kind == "b" else (a.tolist() if a.ndim else float(a))
    return out


class EpisodeScore:
    """One episode's score as it runs: fed every step's outcome, it says when the episode is over (the task's
    end, `settle_steps` after the first success, or the time limit) and what it scored. `evaluate_episode` runs one
    env with it; `evaluate_batch` runs several in lockstep, one score each."""

    def __init__(self, env, seed: int, settle_steps: int = 0):
        self.env, self.seed, self.settle_steps = env, seed, settle_steps
        self.history = GraspHistory()
        self.total, self.steps = 0.0, 0
        self.first: int | None = None  # the step of the first success
        self.info: dict = {}
        self.done = False

    def step(self, reward, terminated: bool, truncated: bool, info: dict) -> bool:
        """Add one step's outcome; returns whether the episode is over."""
        self.steps += 1
        self.total += float(reward)
        watch_grasp(self.env, self.history)
        if self.first is None and info["success"]:
            self.first = self.steps
        if self.first is not None:  # the task ends an episode at its first success; settling runs it on
            terminated = self.steps - self.first >= self.settle_steps
        self.info = info
        self.done = bool(terminated or truncated)
        return self.done

    def result(self) -> EpisodeResult:
        env, info = self.env, self.info
        at_end = bool(info["success"])
        headline = at_end if self.settle_steps > 0 else self.first is not None
        return EpisodeResult(
            seed=self.seed,
            success=headline,
            length=self.steps,
            steps_to_success=self.first,
            episode_return=self.total,
            criteria=criteria(env, info),
            failure=None if headline else failure_category(env, info, self.history),
            config=env.unwrapped.episode_config(),
            final=_scalars(info),
            physics_error=info.get("physics_error"),
            success_once=self.first is not None,
            success_at_end=at_end,
        )


def evaluate_episode(env, policy, seed: int, frames: list | None = None, settle_steps: int = 0) -> EpisodeResult:
    """Run `policy` on `seed` to the end (`settle_steps` after the first success, or the time limit); if `frames` is
    a list, append a rendered frame per state to it."""
    obs, info = env.reset(seed=seed)
    policy.reset(env, seed, obs, info)
    score = EpisodeScore(env, seed, settle_steps)
    if frames is not None:
        frames.append(env.render())
    while True:
        obs, reward, terminated, truncated, info = env.step(policy.act(obs))
        if frames is not None:
            frames.append(env.render())
        if score.step(reward, terminated, truncated, info):
            return score.result()


def evaluate_batch(envs: list, policy, seeds: list[int], settle_steps: int = 0) -> list[EpisodeResult]:
    """Run `policy` on `seeds`, one env each, in lockstep: one `policy.act_batch` call per control step for every
    episode of the batch. An episode that ends is frozen (its env no longer steps, its last observation still
    fills its row of the policy's batch, its action is dropped) until the batch ends."""
    envs = envs[: len(seeds)]
    resets = [env.reset(seed=seed) for env, seed in zip(envs, seeds, strict=True)]
    obs = [o for o, _ in resets]
    policy.reset_batch(envs, seeds, obs, [i for _, i in resets])
    scores = [EpisodeScore(env, seed, settle_steps) for env, seed in zip(envs, seeds, strict=True)]
    while not all(s.done for s in scores):
        actions = policy.act_batch(obs, [not s.done for s in scores])
        for i, (env, score) in enumerate(zip(envs, scores, strict=True)):
            if score.done:
                continue
            obs[i], reward, terminated, truncated, info = env.step(actions[i])
            score.step(reward, terminated, truncated, info)
    return [s.result() for s in scores]
