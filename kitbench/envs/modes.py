"""The observation and reward modes every task supports, and the check that names valid choices."""

from __future__ import annotations

OBS_MODES = ("none", "state", "state_dict", "rgb", "rgbd")
REWARD_MODES = ("dense", "normalized_dense", "sparse", "none")
IMAGE_OBS_MODES = ("rgb", "rgbd")


def check_choice(kind: str, value, choices) -> None:
    if value not in choices:
        raise ValueError(f"unknown {kind} {value!r}; valid choices: {', '.join(map(str, choices))}")
