"""The LeRobot feature schema of a kitbench dataset, derived from the environment it records."""

from __future__ import annotations

from kitbench.robots.panda import ARM_JOINTS

ACTION_NAMES = {
    "pd_joint_delta_pos": [f"delta_{j}" for j in ARM_JOINTS],
    "pd_joint_pos": list(ARM_JOINTS),
    "pd_ee_delta_pos": ["dx", "dy", "dz"],
    "pd_ee_delta_pose": ["dx", "dy", "dz", "drx", "dry", "drz"],
    "pd_ee_pose": ["x", "y", "z", "rx", "ry", "rz"],
}
POSE_NAMES = ["x", "y", "z", "qw", "qx", "qy", "qz"]


def _vector(names: list[str], dtype: str = "float32") -> dict:
    return {"dtype": dtype, "shape": (len(names),), "names": names}


def environment_state_names(env) -> list[str]:
    u = env.unwrapped
    fields = u._task_state(u._last_info)
    names = []
    for key in u.environment_state_keys:
        size = int(fields[key].size)
        if size == 7 and key.endswith("pose"):
            names += [f"{key}.{n}" for n in POSE_NAMES]
        elif size == 1:
            names.append(key)
        else:
            names += [f"{key}.{i}" for i in range(size)]
    return names


def dataset_features(env) -> dict:
    """`observation.*` are policy inputs and `action` the policy output; the rest is bookkeeping lerobot's
    policies ignore (`commanded_ee_pose` is the controller's TCP target, base frame, for task-space training)."""
    u = env.unwrapped
    features = {
        "observation.state": _vector([*ARM_JOINTS, "gripper_opening"]),
        "observation.environment_state": _vector(environment_state_names(env)),
    }
    for name in u.camera_names:
        spec = u._cameras[name].spec
        features[f"observation.images.{name}"] = {
            "dtype": "video", "shape": (spec.height, spec.width, 3), "names": ["height", "width", "channels"],
        }
    features["action"] = _vector([*ACTION_NAMES[u.control_mode], "gripper"])
    features["commanded_ee_pose"] = _vector(POSE_NAMES)
    features["next.reward"] = {"dtype": "float32", "shape": (1,), "names": None}
    features["next.done"] = {"dtype": "bool", "shape": (1,), "names": None}
    features["next.success"] = {"dtype": "bool", "shape": (1,), "names": None}
    features["episode_seed"] = {"dtype": "int64", "shape": (1,), "names": None}
    return features
