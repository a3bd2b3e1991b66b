"""Observation assembly: nested state dicts, their flat vector form, and matching gymnasium spaces."""

from __future__ import annotations

import numpy as np
from gymnasium import spaces


def flatten_state(state: dict) -> np.ndarray:
    """Concatenate every leaf of a nested state dict, in insertion order, as float32."""
    parts = []
    for value in state.values():
        if isinstance(value, dict):
            parts.append(flatten_state(value))
        else:
            parts.append(np.asarray(value, dtype=np.float32).reshape(-1))
    return np.concatenate(parts) if parts else np.zeros(0, dtype=np.float32)


def space_for(obs) -> spaces.Space:
    """A space that contains an example observation: unbounded floats, full-range integers."""
    if isinstance(obs, dict):
        return spaces.Dict({k: space_for(v) for k, v in obs.items()})
    arr = np.asarray(obs)
    if arr.dtype == np.uint8:
        return spaces.Box(0, 255, arr.shape, np.uint8)
    if np.issubdtype(arr.dtype, np.integer):
        info = np.iinfo(arr.dtype)
        return spaces.Box(info.min, info.max, arr.shape, arr.dtype)
    if arr.dtype == np.bool_:
        return spaces.MultiBinary(arr.shape)
    return spaces.Box(-np.inf, np.inf, arr.shape, np.float32)


def pose7(pose) -> np.ndarray:
    """A SAPIEN pose as [x, y, z, qw, qx, qy, qz] float32."""
    return np.concatenate([pose.p, pose.q]).astype(np.float32)
