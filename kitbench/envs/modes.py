"""The observation and reward modes every task supports (`kitbench.errors.check_choice` refuses others)."""

from __future__ import annotations

OBS_MODES = ("none", "state", "state_dict", "rgb", "rgbd")
REWARD_MODES = ("dense", "normalized_dense", "sparse", "none")
IMAGE_OBS_MODES = ("rgb", "rgbd")
