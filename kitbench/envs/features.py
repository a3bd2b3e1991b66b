"""The LeRobot features of a kitbench env: the names, types and shapes of its observations and actions.

Defined once, from the env itself, and used by the recorder (a dataset's schema), the runner of trained
lerobot policies (does the checkpoint fit the env?) and the LeRobot env plugin (`--env.type=kitbench`).
Shapes follow LeRobot's dataset convention: images (height, width, channels).
"""

from __future__ import annotations

from kitbench.envs.tabletop import POSE_NAMES

__all__ = ["POSE_NAMES", "action_feature", "action_names", "observation_features", "vector"]

# The arm part of each end-effector mode's action; joint modes name the robot's arm joints (`action_names`).
EE_ACTION_NAMES = {
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
    features = {STATE: vector(u.robot_state_names), ENVIRONMENT_STATE: vector(u.environment_state_names())}
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


def action_names(env) -> list[str]:
    """One name per action entry: the arm part of the env's control mode, the gripper, then the robot's body
    joint deltas and base velocities (`kitbench.robots.spec`)."""
    u = env.unwrapped
    spec = u.robot_spec
    mode = u.control_mode
    if mode in EE_ACTION_NAMES:
        arm = EE_ACTION_NAMES[mode]
    elif mode == "pd_joint_pos":
        arm = list(spec.arm_joints)
    else:  # joint delta modes
        arm = [f"delta_{j}" for j in spec.arm_joints]
    return [*arm, "gripper", *spec.extra_action_names]


def action_feature(env) -> dict:
    """The action vector (`action_names`)."""
    return vector(action_names(env))
