"""One evaluation episode: the policy acts until the episode ends; only what a report needs is kept.

The task ends an episode at its first success; with `settle_steps` it runs on that many steps more (or to the
time limit), and the episode has two outcomes, as ManiSkill reports them: `success_once` (successful at any step)
and `success_at_end` (successful at the last step). `success` is the suite's headline of the two.

Nothing is copied per step beyond a grasp check (and, for a video, the rendered frame), so scoring runs at the
speed of the simulator and the policy.
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


def evaluate_episode(env, policy, seed: int, frames: list | None = None, settle_steps: int = 0) -> EpisodeResult:
    """Run `policy` on `seed` to the end (`settle_steps` after the first success, or the time limit); if `frames` is
    a list, append a rendered frame per state to it."""
    u = env.unwrapped
    obs, info = env.reset(seed=seed)
    policy.reset(env, seed, obs, info)
    history = GraspHistory()
    if frames is not None:
        frames.append(env.render())
    total, steps, first = 0.0, 0, None
    while True:
        obs, reward, terminated, truncated, info = env.step(policy.act(obs))
        steps += 1
        total += float(reward)
        watch_grasp(env, history)
        if frames is not None:
            frames.append(env.render())
        if first is None and info["success"]:
            first = steps
        if first is not None:  # the task ends an episode at its first success; settling runs it on
            terminated = steps - first >= settle_steps
        if terminated or truncated:
            break
    at_end = bool(info["success"])
    headline = at_end if settle_steps > 0 else first is not None
    return EpisodeResult(
        seed=seed,
        success=headline,
        length=steps,
        steps_to_success=first,
        episode_return=total,
        criteria=criteria(env, info),
        failure=None if headline else failure_category(env, info, history),
        config=u.episode_config(),
        final=_scalars(info),
        physics_error=info.get("physics_error"),
        success_once=first is not None,
        success_at_end=at_end,
    )
