"""Policies by name, as the command line spells them."""

from __future__ import annotations

from kitbench.errors import KitbenchError

BUILTIN = ("expert", "random", "zero")


def make_policy(spec: str, device: str = "cpu", options: dict | None = None):
    """`expert`, `random`, `zero`, `replay:<dataset>[:episode]` or `lerobot:<checkpoint>` (whose network runs on
    `device`: auto, cpu or cuda, with its config's `options` set for this run). Options for a policy that has no
    config are refused."""
    if options and not spec.startswith("lerobot:"):
        raise KitbenchError(f"policy options {options} need a lerobot:<checkpoint> policy; {spec!r} has no settings")
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

        return LeRobotPolicy(spec[len("lerobot:") :], device, options)
    raise KitbenchError(
        f"unknown policy {spec!r}; valid choices: {', '.join(BUILTIN)}, replay:<dataset>[:episode], "
        f"lerobot:<checkpoint>"
    )
