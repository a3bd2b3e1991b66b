"""Policies by name, as the command line spells them."""

from __future__ import annotations

from kitbench.errors import KitbenchError

BUILTIN = ("expert", "random", "zero")


def make_policy(spec: str):
    """`expert`, `random`, `zero`, `replay:<dataset>[:episode]` or `lerobot:<checkpoint>`."""
    if spec == "expert":
        from kitbench.policies.expert import ExpertPolicy

        return ExpertPolicy()
    if spec == "random":
        from kitbench.policies.baselines import RandomPolicy

        return RandomPolicy()
    if spec == "zero":
        from kitbench.policies.baselines import ZeroPolicy

        return ZeroPolicy()
    if spec.startswith("replay:"):
        from kitbench.policies.replay import ReplayPolicy

        root, _, episode = spec[len("replay:") :].partition(":")
        return ReplayPolicy(root, int(episode) if episode else None)
    if spec.startswith("lerobot:"):
        from kitbench.policies.lerobot_policy import LeRobotPolicy

        return LeRobotPolicy(spec[len("lerobot:") :])
    raise KitbenchError(
        f"unknown policy {spec!r}; valid choices: {', '.join(BUILTIN)}, replay:<dataset>[:episode], "
        f"lerobot:<checkpoint>"
    )
