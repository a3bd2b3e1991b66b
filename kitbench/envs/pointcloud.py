"""Point clouds: every camera's pixels fused into one world-frame cloud (`fuse_cameras`, the env's obs mode
`pointcloud`), and the seeded fixed-size sample of it that datasets store and policies read (`PointSampler`).

The env's cloud (`obs["pointcloud"]`, ManiSkill's layout) holds every camera pixel, with w = 0 for those that see
nothing or lie beyond the env's `pointcloud_range`. A dataset stores a fixed number of points per frame (LeRobot
features have fixed shapes): `PointSampler` draws them from the kept points, with a generator seeded by the episode's
seed, so the same episode gives the same points wherever it is recorded or evaluated.
"""

from __future__ import annotations

import numpy as np

# Points per frame a dataset stores unless a recipe says otherwise (`pointcloud_points`): PointNet-style policies
# for tabletop manipulation commonly read 512-1024 points. Of LiftPegUpright's 16,384 camera pixels 11,122 are kept
# at reset (seed 1); of AssemblingKits' 32,768, 32,106.
DEFAULT_POINTS = 1024


def fuse_cameras(cameras: dict, sensor_data: dict, sensor_param: dict, max_depth: float) -> dict[str, np.ndarray]:
    """Every camera's pixels as one world-frame cloud, ManiSkill's layout: `xyzw` (N, 4) float32 with w 1 for a
    point that sees something within `max_depth` (m, along its camera's viewing axis) and 0 else, `rgb` (N, 3) uint8
    and `segmentation` (N, 1) uint16; N is the cameras' pixel count, in camera then row-major pixel order.
    `cameras` are `kitbench.sim.cameras.Camera`s after `take_picture`; `sensor_data` and `sensor_param` the
    observation's, with rgb and segmentation."""
    xyzw, rgb, segmentation = [], [], []
    for name, camera in cameras.items():
        position = camera.position().reshape(-1, 4)  # OpenGL camera frame, looking down -z
        keep = (position[:, 3] < 1) & (-position[:, 2] <= max_depth)
        to_world = sensor_param[name]["cam2world_gl"].astype(np.float64)
        world = position[:, :3].astype(np.float64) @ to_world[:3, :3].T + to_world[:3, 3]
        xyzw.append(np.concatenate([world, keep[:, None]], axis=1).astype(np.float32))
        rgb.append(sensor_data[name]["rgb"].reshape(-1, 3))
        segmentation.append(sensor_data[name]["segmentation"].reshape(-1, 1))
    return {"xyzw": np.concatenate(xyzw), "rgb": np.concatenate(rgb), "segmentation": np.concatenate(segmentation)}


class PointSampler:
    """`points` points of each frame's cloud, drawn without replacement from the kept points (with replacement
    when fewer are kept; all zeros when none is), in the order they come in the env's cloud."""

    def __init__(self, points: int, seed: int):
        self.points = points
        self._rng = np.random.default_rng(seed)

    def sample(self, cloud: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """`xyz` (points, 3) float32 metres in the world frame, `rgb` (points, 3) uint8, `segmentation` (points, 1)
        uint16 (the env's `segmentation_id_map`)."""
        kept = np.flatnonzero(cloud["xyzw"][:, 3] > 0)
        n = self.points
        if len(kept) == 0:
            return {
                "xyz": np.zeros((n, 3), np.float32),
                "rgb": np.zeros((n, 3), np.uint8),
                "segmentation": np.zeros((n, 1), np.uint16),
            }
        chosen = np.sort(self._rng.choice(kept, n, replace=len(kept) < n))
        return {
            "xyz": np.ascontiguousarray(cloud["xyzw"][chosen, :3]),
            "rgb": cloud["rgb"][chosen],
            "segmentation": cloud["segmentation"][chosen],
        }
