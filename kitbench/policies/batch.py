"""Policies that act on one env at a time, run over a batch of episodes (`evaluation.episode.evaluate_batch`).

A policy with `reset_batch` and `act_batch` (a trained lerobot policy) batches itself: one network call a step
for every episode. Any other (the expert, the baselines, replays) keeps state per episode, so a batch gets one
instance per episode, each acting as it does alone: the results are those of unbatched episodes, exactly.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from kitbench.policies.base import BatchPolicy


class IndependentPolicies:
    """One instance of a policy per episode of a batch, made by `make` as the batch needs them."""

    def __init__(self, make: Callable[[], object]):
        self._make = make
        self._policies: list = []

    def reset_batch(self, envs: list, seeds: list[int], obs: list, infos: list[dict]) -> None:
        while len(self._policies) < len(envs):
            self._policies.append(self._make())
        for policy, env, seed, o, info in zip(self._policies, envs, seeds, obs, infos, strict=False):
            policy.reset(env, seed, o, info)

    def act_batch(self, obs: list, active: list[bool]) -> list[np.ndarray | None]:
        """Each active episode's action; None for a finished one (it is not asked: a finished expert or replay
        has nothing more to say)."""
        return [p.act(o) if a else None for p, o, a in zip(self._policies, obs, active, strict=False)]


def batched(policy, make: Callable[[], object]):
    """`policy` when it batches itself, else `IndependentPolicies` of instances made by `make` (the first of them
    `policy`)."""
    if isinstance(policy, BatchPolicy):
        return policy
    first = [policy]
    return IndependentPolicies(lambda: first.pop() if first else make())
