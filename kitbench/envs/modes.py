"""The observation and reward modes every task supports (`kitbench.errors.check_choice` refuses others).

Camera modes follow ManiSkill 3's names: a camera texture (`rgb`, `depth`, `segmentation`) or several joined by
`+` in that order, `rgbd` for `rgb+depth`, and `pointcloud` (every camera's pixels fused into one world-frame
cloud with rgb and segmentation per point). `camera_textures` says which textures a mode renders.
"""

from __future__ import annotations

import itertools

from kitbench.envs import modalities

TEXTURES = tuple(modalities.TEXTURES)  # "rgb", "depth", "segmentation": one class each
# every non-empty combination of the textures, in TEXTURES' order ("rgb+depth+segmentation")
_TEXTURE_MODES = tuple(
    "+".join(combo) for n in range(1, len(TEXTURES) + 1) for combo in itertools.combinations(TEXTURES, n)
)
POINTCLOUD = "pointcloud"
IMAGE_OBS_MODES = (*_TEXTURE_MODES[:1], "rgbd", *_TEXTURE_MODES[1:], POINTCLOUD)
"""Every obs mode that renders cameras."""
OBS_MODES = ("none", "state", "state_dict", *IMAGE_OBS_MODES)
REWARD_MODES = ("dense", "normalized_dense", "sparse", "none")


def camera_textures(obs_mode: str) -> frozenset[str]:
    """The textures an obs mode renders per camera: none for the state modes, all three for `pointcloud` (a
    point's position comes from depth, its colour and label from rgb and segmentation)."""
    if obs_mode == POINTCLOUD:
        return frozenset(TEXTURES)
    if obs_mode == "rgbd":
        return frozenset(("rgb", "depth"))
    if obs_mode in _TEXTURE_MODES:
        return frozenset(obs_mode.split("+"))
    return frozenset()
