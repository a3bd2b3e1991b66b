"""The LeRobot feature schema of a kitbench dataset: the env's own features plus the recorder's bookkeeping."""

from __future__ import annotations

from kitbench.envs.features import POSE_NAMES, action_feature, modality, observation_features, vector
from kitbench.envs.pointcloud import DEFAULT_POINTS

# How rgb frames are stored (`kitbench record --rgb-storage`): "video", h264 (LeRobot's default, lossy); "images",
# PNG in the parquet files (lossless, ~5x the bytes at 128x128; docs/training-input.md).
RGB_STORAGES = ("video", "images")


def dataset_features(env, points: int = DEFAULT_POINTS, rgb_storage: str = "video") -> dict:
    """`observation.*` are policy inputs and `action` the policy output; the rest is bookkeeping lerobot's
    policies ignore (`commanded_ee_pose` is the controller's TCP target, base frame, for task-space training;
    `executed_action` is what the robot executed: `action` plus the noise of `--action-noise`, else equal)."""
    features = observation_features(env, points=points)
    if rgb_storage == "images":
        for name, feature in features.items():
            if modality(name) == "rgb":
                feature["dtype"] = "image"
    features["action"] = action_feature(env)
    features["executed_action"] = action_feature(env)
    features["commanded_ee_pose"] = vector(POSE_NAMES)
    features["next.reward"] = {"dtype": "float32", "shape": (1,), "names": None}
    features["next.done"] = {"dtype": "bool", "shape": (1,), "names": None}
    features["next.success"] = {"dtype": "bool", "shape": (1,), "names": None}
    features["episode_seed"] = {"dtype": "int64", "shape": (1,), "names": None}
    return features
