"""What kitbench asks of a policy (`Policy`), and the capabilities a policy may add, each a typed Protocol the
rest of kitbench tests for instead of probing attributes.

- `Phased`: names the phase it is in (the expert: approach, grasp, ...): action noise confined to phases, and the
  MCAP log's `/planner` topic.
- `TcpTargeted`: the TCP pose it aims at (the expert's planner), logged beside the phase.
- `HasRequirements`: the modes and robot the env must have for it (a trained policy's training data's).
- `ChecksEnv`: refuses an env it does not fit, in one line (a trained policy's inputs and action size).
- `Labels`: labels its own frames with something other than what it executes (a conversion's replay).
- `BatchPolicy`: acts for several episodes in lockstep with one call (a trained lerobot policy).
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class Policy(Protocol):
    name: str

    def reset(self, env, seed: int, obs, info: dict) -> None: ...

    def act(self, obs) -> np.ndarray: ...


@runtime_checkable
class Phased(Protocol):
    @property
    def phase(self) -> str | None: ...


@runtime_checkable
class TcpTargeted(Protocol):
    @property
    def tcp_target(self) -> np.ndarray | None: ...


@runtime_checkable
class HasRequirements(Protocol):
    def requirements(self) -> dict[str, str]: ...


@runtime_checkable
class ChecksEnv(Protocol):
    def check(self, env) -> None: ...


@runtime_checkable
class Labels(Protocol):
    @property
    def label(self) -> np.ndarray | None: ...


@runtime_checkable
class BatchPolicy(Protocol):
    def reset_batch(self, envs: list, seeds: list[int], obs: list, infos: list[dict]) -> None: ...

    def act_batch(self, obs: list, active: list[bool]) -> Any: ...


def phase_of(policy: object) -> str | None:
    return policy.phase if isinstance(policy, Phased) else None


def tcp_target_of(policy: object) -> np.ndarray | None:
    return policy.tcp_target if isinstance(policy, TcpTargeted) else None


def label_of(policy: object) -> np.ndarray | None:
    """The label of the step the policy just acted in, if it labels its own frames."""
    return policy.label if isinstance(policy, Labels) else None


def requirements_of(policy: object) -> dict[str, str]:
    return policy.requirements() if isinstance(policy, HasRequirements) else {}


def check_fits(policy: object, env) -> None:
    if isinstance(policy, ChecksEnv):
        policy.check(env)
