"""A camera texture (rgb, depth, segmentation) as one class: everything kitbench does with it once the env has
rendered it. Its dataset feature (name, dtype, shape, info), how stock `LeRobotDataset` hands it to a policy, what
the dataset card says it holds and how the MCAP log carries it. Features, policy inputs, cards and logs ask the
registry (`TEXTURES`), never a texture by name, so a new texture is a subclass here and the line of the env that
renders it (`TabletopEnv._observation`).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import ClassVar

import numpy as np

HWC = ["height", "width", "channels"]


class Texture(ABC):
    """One camera texture: `observation.images.<camera><suffix>` in a dataset, `name` in the env's `sensor_data`."""

    name: ClassVar[str]
    suffix: ClassVar[str]  # after `observation.images.<camera>`
    description: ClassVar[str]  # what the dataset card says a frame holds
    # How an MCAP log carries it: "jpeg" (a CompressedImage of the picture), "float" (a RawImage 32FC1 of the one
    # channel), "labels" (a CompressedImage PNG with one colour per id); topic `/camera/<camera><mcap_topic>`.
    mcap: ClassVar[str]
    mcap_topic: ClassVar[str]

    @abstractmethod
    def feature(self, height: int, width: int, ids: dict) -> dict:
        """The LeRobot feature of one camera (`ids`: the segmentation id table, where a feature keeps it)."""

    @abstractmethod
    def loaded(self, value: np.ndarray, depth_unit: str) -> np.ndarray:
        """The env's (H, W, C) frame as stock `LeRobotDataset` returns it (channels first), what a policy reads."""


class Rgb(Texture):
    name, suffix, mcap, mcap_topic = "rgb", "", "jpeg", ""
    description = "camera image"

    def feature(self, height: int, width: int, ids: dict) -> dict:
        return {"dtype": "video", "shape": (height, width, 3), "names": HWC}

    def loaded(self, value: np.ndarray, depth_unit: str) -> np.ndarray:
        return np.ascontiguousarray(value.transpose(2, 0, 1)).astype(np.float32) / np.float32(255)


class Depth(Texture):
    name, suffix, mcap, mcap_topic = "depth", "_depth", "float", "/depth"
    description = (
        "depth along the viewing axis, stored in metres (within 1 mm; stock `LeRobotDataset` returns millimetres "
        'unless `depth_output_unit="m"`), 0 where the pixel sees nothing'
    )

    def feature(self, height: int, width: int, ids: dict) -> dict:
        return {
            "dtype": "video",
            "shape": (height, width, 1),
            "names": HWC,
            # LeRobot adds depth_unit "m" (float frames) and the quantiser's settings when it encodes
            "info": {"is_depth_map": True, "depth": "along the viewing axis (z-depth); 0: the pixel sees nothing"},
        }

    def loaded(self, value: np.ndarray, depth_unit: str) -> np.ndarray:
        scale = {"mm": 1000.0, "m": 1.0}[depth_unit]
        return np.ascontiguousarray(value.transpose(2, 0, 1)) * np.float32(scale)


class Segmentation(Texture):
    name, suffix, mcap, mcap_topic = "segmentation", "_segmentation", "labels", "/segmentation"
    description = "segmentation id per pixel (the id-to-name table is in meta/info.json)"

    def feature(self, height: int, width: int, ids: dict) -> dict:
        # a lossless 16-bit PNG image: a lossy codec would blend ids at every edge
        return {"dtype": "image", "shape": (height, width, 1), "names": HWC, "info": ids}

    def loaded(self, value: np.ndarray, depth_unit: str) -> np.ndarray:
        return np.ascontiguousarray(value.transpose(2, 0, 1)).astype(np.float32)


TEXTURES: dict[str, Texture] = {t.name: t for t in (Rgb(), Depth(), Segmentation())}


def texture_of(feature_name: str, images_prefix: str = "observation.images.") -> Texture | None:
    """The texture a dataset feature holds (None for a feature that is not a camera's); the longest suffix wins,
    rgb's being empty."""
    if not feature_name.startswith(images_prefix):
        return None
    found = [t for t in TEXTURES.values() if t.suffix and feature_name.endswith(t.suffix)]
    return max(found, key=lambda t: len(t.suffix)) if found else TEXTURES["rgb"]
