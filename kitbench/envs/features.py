"""The LeRobot features of a kitbench env: the names, types and shapes of its observations and actions.

Defined once, from the env itself, and used by the recorder (a dataset's schema), the runner of trained
lerobot policies (does the checkpoint fit the env?) and the LeRobot env plugin (`--env.type=kitbench`).
Shapes follow LeRobot's dataset convention: images (height, width, channels).
"""

from __future__ import annotations

from kitbench.envs.tabletop import POSE_NAMES, ROBOT_STATE_NAMES

__all__ = ["ACTION_NAMES", "POSE_NAMES", "action_feature", "observation_features", "vector"]
from kitbench.robots.panda import ARM_JOINTS

ACTION_NAMES = {
    "pd_joint_delta_pos": [f"delta_{j}" for j in ARM_JOINTS],
    "pd_joint_target_delta_pos": [f"delta_{j}" for j in ARM_JOINTS],
    "pd_joint_pos": list(ARM_JOINTS),
    "pd_ee_delta_pos": ["dx", "dy", "dz"],
    "pd_ee_target_delta_pos": ["dx", "dy", "dz"],
    "pd_ee_delta_pose": ["dx", "dy", "dz", "drx", "dry", "drz"],
    "pd_ee_target_delta_pose": ["dx", "dy", "dz", "drx", "dry", "drz"],
    "pd_ee_pose": ["x", "y", "z", "rx", "ry", "rz"],
}
STATE = "observation.state"
ENVIRONMENT_STATE = "observation.environment_state"
IMAGES = "observation.images."


def vector(names, dtype: str = "float32") -> dict:
    return {"dtype": dtype, "shape": (len(names),), "names": list(names)}


def observation_features(env, images: bool | None = None) -> dict[str, dict]:
    """`observation.state`, `observation.environment_state` and, with `images` (default: when the env's
    observations have cameras), one `observation.images.<camera>` per camera of the task's image modes."""
    u = env.unwrapped
    features = {STATE: vector(ROBOT_STATE_NAMES), ENVIRONMENT_STATE: vector(u.environment_state_names())}
    if images is None:
        images = bool(u.camera_names)
    if images:
        for spec in u.camera_specs():
            features[IMAGES + spec.name] = {
                "dtype": "video",
                "shape": (spec.height, spec.width, 3),
                "names": ["height", "width", "channels"],
            }
    return features


def action_feature(env) -> dict:
    """The action vector: the arm part of the env's control mode, then the gripper."""
    u = env.unwrapped
    return vector([*ACTION_NAMES[u.control_mode], "gripper"])
