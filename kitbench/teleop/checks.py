"""The recording settings a teleoperated recording refuses, one line each, whether a flag or a recipe set them (the
SO-101 recipes ask for 2 workers): a person drives one episode at a time, in this process, and what they do is
the data."""

from __future__ import annotations

from kitbench.errors import KitbenchError

SOURCE = "teleop"


def is_teleop(policy: str) -> bool:
    """Whether a policy spelling names the teleop source (`teleop:<device>`)."""
    return policy.partition(":")[0] == SOURCE


def check_record_settings(policy: str, workers: int, executor: str, shard_episodes: int, action_noise: float) -> None:
    """Refuse what cannot be teleoperated: more workers, Ray, shards, action noise."""
    if not is_teleop(policy):
        return
    if executor != "local":
        raise KitbenchError(
            f"policy {policy} records in this process, where the person drives: record with --executor local "
            f"(got {executor})"
        )
    if workers != 1:
        raise KitbenchError(f"policy {policy} drives one episode at a time: record with --workers 1 (got {workers})")
    if shard_episodes:
        raise KitbenchError(
            f"policy {policy} records on one writer: record with --shard-episodes 0 (got {shard_episodes})"
        )
    if action_noise:
        raise KitbenchError(
            f"policy {policy} stores what the person commanded: record with --action-noise 0 (got {action_noise})"
        )
