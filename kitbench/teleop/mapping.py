"""A device's action (a dict in lerobot's names and units) onto the env's action (the robot's units, the recipe's
control mode), for three kinds of device, told apart by what `get_action` returns:

- a leader arm (`so101_leader`, `so100_leader`, `koch_leader`, ...): `<motor>.pos`, joints in degrees and the jaw
  from 0 (closed) to 100 (open), LeRobot's units, which are the SO-101's own (`kitbench.robots.units.SO_FOLLOWER`):
  each motor lands on the simulated joint of the same name, clipped to the simulated joint's limits (counted), in
  any control mode (through `kitbench.policies.joint_targets.joint_target_to_action`);
- end-effector deltas (`gamepad`, `keyboard_ee`): `delta_x`, `delta_y`, `delta_z` (each -1..1 of full deflection,
  in the robot's base frame) and `gripper` (0 close, 1 stay, 2 open), onto the end-effector delta modes;
- end-effector deltas with the turn (`kitbench_keyboard`, `kitbench_gamepad`): those and `delta_pitch` (about the
  TCP's y, the line between the fingers) and `delta_yaw` (about the base's vertical), onto the pose modes;
- a phone (`phone`): its pose since the press that enabled it, through lerobot's own axis mapping
  (`MapPhoneActionToRobotAction`), latched on the commanded TCP at that press as lerobot's `EEReferenceAndDelta`
  does, and its gripper velocity; onto the end-effector delta modes and `pd_ee_pose`.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from kitbench.control.controllers import BASE, modes_where
from kitbench.envs.interface import KitbenchEnv
from kitbench.errors import KitbenchError
from kitbench.geometry import axis_angle_to_matrix
from kitbench.robots.spec import CLOSED, OPEN

# (env, arm joint targets in radians, gripper command -1 closed .. 1 open) -> the env's action in its mode; the
# policies' `joint_target_to_action`, handed in so that this package stays below the policies
JointAction = Callable[[KitbenchEnv, np.ndarray, float], np.ndarray]

DELTA_KEYS = ("delta_x", "delta_y", "delta_z")
TURN_KEYS = ("delta_pitch", "delta_yaw")
PHONE_KEYS = ("phone.pos", "phone.rot", "phone.raw_inputs", "phone.enabled")
# lerobot's discrete gripper classes (`GamepadTeleop.GripperAction`): 0 close, 1 stay, 2 open
GRIPPER_CLOSE, GRIPPER_OPEN = 0.5, 1.5
JAW_OPEN = 100.0  # a jaw in percent, 0 closed .. 100 open


@dataclass
class ClipCount:
    """Values a device gave beyond the simulated robot's limits, clipped to them, by name."""

    values: int = 0  # values mapped in all
    clipped: Counter = field(default_factory=Counter)

    @property
    def total(self) -> int:
        return sum(self.clipped.values())

    def line(self) -> str:
        """One line for the end of a recording."""
        if not self.total:
            return f"no value beyond the simulated joint limits ({self.values} mapped)"
        names = ", ".join(f"{name} {n}" for name, n in self.clipped.most_common())
        return f"{self.total} of {self.values} values beyond the simulated joint limits clipped to them ({names})"


class Mapping(Protocol):
    kind: str  # what messages call the device's kind
    modes: tuple[str, ...] | None  # the control modes it drives (None: every mode)

    def reset(self, env: KitbenchEnv) -> None: ...

    def action(self, env: KitbenchEnv, device_action: dict[str, Any]) -> np.ndarray: ...


def commanded_tcp(env: KitbenchEnv) -> np.ndarray:
    """The 4x4 base-frame TCP pose the controller drives to (its TCP target, else its joint target's)."""
    controller = env.controller
    target = controller.tcp_target
    return (controller.kinematics.tcp_pose(controller.joint_target) if target is None else target).copy()


def tcp_target_to_action(env: KitbenchEnv, target: np.ndarray, gripper: float) -> np.ndarray:
    """The action of an end-effector mode that drives the TCP to `target` (4x4, base frame) with the gripper at
    `gripper` (-1 closed .. 1 open), in the robot's units, within the action box; deltas are taken from what the
    mode applies them to, as `joint_target_to_action` takes them (`Controller.tcp_action`)."""
    return _in_box(env, env.controller.tcp_action(target, env.robot.arm_qpos()), gripper)


def _in_box(env: KitbenchEnv, arm: np.ndarray, gripper: float) -> np.ndarray:
    extra = np.zeros(len(env.robot_spec.extra_action_names))  # body joints and base hold still
    action = env.action_from_sim(np.concatenate([arm, [gripper], extra]).astype(np.float32))
    space = env.action_space
    return np.clip(action, space.low, space.high)


def jaw_command(percent: float) -> float:
    """A jaw position in percent (0 closed .. 100 open) as the simulation's gripper command (-1 closed .. 1 open),
    the same scale `SO_FOLLOWER` puts on the SO-101's jaw."""
    return percent / 50.0 - 1.0


class JointMapping:
    """A leader arm, joint for joint: `<motor>.pos` in the robot's units (the SO-101's degrees and jaw percent)."""

    kind: str = "leader arm"
    modes: tuple[str, ...] | None = None

    def __init__(self, env: KitbenchEnv, joint_action: JointAction):
        self.joint_action = joint_action
        spec = env.robot_spec
        units = spec.units
        self.arm_keys = units.joint_names(spec)
        self.jaw_key = units.gripper_action_name(spec) if units.gripper_percent else None
        self.per_radian = units.per_radian
        self.limits = np.asarray(env.robot.arm_limits, dtype=np.float64)
        self.clips = ClipCount()

    @staticmethod
    def names(env: KitbenchEnv) -> list[str]:
        """The keys a leader of this robot gives: its arm joints' and its jaw's, in its units' names."""
        spec = env.robot_spec
        units = spec.units
        jaw = [units.gripper_action_name(spec)] if units.gripper_percent else []
        return units.joint_names(spec) + jaw

    def reset(self, env: KitbenchEnv) -> None:
        """Nothing: a leader arm holds no state between steps."""

    def targets(self, device_action: dict[str, Any]) -> tuple[np.ndarray, float]:
        """The arm's joint targets (radians) and the gripper command (-1 closed .. 1 open) the device's values
        set, each clipped to the simulated joint's limits; every clipped value counted."""
        values = np.array([float(device_action[k]) for k in self.arm_keys]) / self.per_radian
        low, high = self.limits[:, 0], self.limits[:, 1]
        arm = np.clip(values, low, high)
        for key, value, kept in zip(self.arm_keys, values, arm, strict=True):
            if value != kept:
                self.clips.clipped[key] += 1
        self.clips.values += len(self.arm_keys)
        gripper = OPEN
        if self.jaw_key is not None:
            percent = float(device_action[self.jaw_key])
            kept_percent = min(max(percent, 0.0), JAW_OPEN)
            if kept_percent != percent:
                self.clips.clipped[self.jaw_key] += 1
            self.clips.values += 1
            gripper = jaw_command(kept_percent)
        return arm, gripper

    def action(self, env: KitbenchEnv, device_action: dict[str, Any]) -> np.ndarray:
        arm, gripper = self.targets(device_action)
        return self.joint_action(env, arm, gripper)

    def offsets(self, env: KitbenchEnv, device_action: dict[str, Any]) -> dict[str, float]:
        """How far each of the device's arm joints is from the simulated arm's (the robot's units)."""
        simulated = np.asarray(env.robot.arm_qpos()) * self.per_radian
        return {
            key: float(device_action[key]) - float(value) for key, value in zip(self.arm_keys, simulated, strict=True)
        }


class DeltaMapping:
    """Position deltas and a discrete gripper (lerobot's gamepad and keyboard_ee): `delta_*` of full deflection
    move the TCP `speed` m/s along the base frame's axes; the orientation holds (the pose modes get no rotation)."""

    kind: str = "end-effector deltas"
    modes: tuple[str, ...] | None = modes_where(lambda c: c.frame == BASE and c.delta)

    def __init__(self, env: KitbenchEnv, speed: float):
        self.step = speed * env.control_timestep  # metres a control step at full deflection
        self.gripper = OPEN

    def reset(self, env: KitbenchEnv) -> None:
        self.gripper = OPEN

    def action(self, env: KitbenchEnv, device_action: dict[str, Any]) -> np.ndarray:
        arm = np.array([float(device_action.get(k, 0.0)) for k in DELTA_KEYS]) * self.step
        self.gripper = gripper_class(device_action, self.gripper)
        if env.controller.turns:
            arm = np.concatenate([arm, np.zeros(3)])
        return _in_box(env, arm, self.gripper)


def gripper_class(device_action: dict[str, Any], held: float) -> float:
    """The gripper command after lerobot's discrete class (0 close, 1 stay, 2 open), from `held`."""
    if "gripper" not in device_action:
        return held
    command = float(device_action["gripper"])
    return CLOSED if command < GRIPPER_CLOSE else OPEN if command > GRIPPER_OPEN else held


class TurnMapping:
    """Deltas with the turn: the commanded TCP moves `speed` m/s along the base frame's axes at full deflection,
    turns `turn_speed` rad/s about the TCP's y (pitch: the line between the fingers) and the base's vertical (yaw),
    from the TCP the controller was last commanded to; the gripper as lerobot's classes latch it."""

    kind: str = "end-effector deltas with the turn"
    modes: tuple[str, ...] | None = modes_where(lambda c: c.turns)

    def __init__(self, env: KitbenchEnv, speed: float, turn_speed: float):
        self.step = speed * env.control_timestep
        self.turn = turn_speed * env.control_timestep
        self.gripper = OPEN

    def reset(self, env: KitbenchEnv) -> None:
        self.gripper = OPEN

    def target(self, commanded: np.ndarray, device_action: dict[str, Any]) -> np.ndarray:
        """Where the deltas take the `commanded` TCP (4x4, base frame) in one control step."""
        values = {k: float(np.clip(device_action.get(k, 0.0), -1.0, 1.0)) for k in (*DELTA_KEYS, *TURN_KEYS)}
        target = commanded.copy()
        target[:3, 3] += np.array([values[k] for k in DELTA_KEYS]) * self.step
        pitch = axis_angle_to_matrix(np.array([0.0, values["delta_pitch"] * self.turn, 0.0]))
        yaw = axis_angle_to_matrix(np.array([0.0, 0.0, values["delta_yaw"] * self.turn]))
        target[:3, :3] = yaw @ commanded[:3, :3] @ pitch
        return target

    def action(self, env: KitbenchEnv, device_action: dict[str, Any]) -> np.ndarray:
        self.gripper = gripper_class(device_action, self.gripper)
        return tcp_target_to_action(env, self.target(commanded_tcp(env), device_action), self.gripper)


class PhoneMapping:
    """A phone: while enabled, the TCP follows the phone's pose since the enabling press, `scale` metres per metre,
    from the TCP commanded at that press; disabled, the TCP holds. The gripper velocity moves the jaw
    `gripper_speed` percent a step per unit (positive opens)."""

    kind: str = "phone"
    modes: tuple[str, ...] | None = modes_where(lambda c: c.frame == BASE)

    def __init__(self, env: KitbenchEnv, platform, scale: float, gripper_speed: float):
        from lerobot.teleoperators.phone.phone_processor import MapPhoneActionToRobotAction

        self.axes = MapPhoneActionToRobotAction(platform=platform)
        self.scale, self.gripper_speed = scale, gripper_speed
        self.reset(env)

    def reset(self, env: KitbenchEnv) -> None:
        self.enabled = False
        self.reference: np.ndarray | None = None
        self.desired: np.ndarray | None = None
        self.jaw = JAW_OPEN

    def action(self, env: KitbenchEnv, device_action: dict[str, Any]) -> np.ndarray:
        # the phone gives nothing while it has no pose
        mapped = self.axes.action(dict(device_action)) if device_action else {"enabled": False, "gripper_vel": 0.0}
        enabled, velocity = bool(mapped["enabled"]), float(mapped["gripper_vel"])
        if enabled:
            if not self.enabled or self.reference is None:
                self.reference = commanded_tcp(env)
            move = np.array([mapped[f"target_{a}"] for a in "xyz"], dtype=np.float64) * self.scale
            turn = np.array([mapped[f"target_w{a}"] for a in "xyz"], dtype=np.float64)
            self.desired = self.reference.copy()
            self.desired[:3, 3] += move
            self.desired[:3, :3] = self.reference[:3, :3] @ axis_angle_to_matrix(turn)
        elif self.desired is None:
            self.desired = commanded_tcp(env)  # never enabled yet: hold where the controller is
        self.enabled = enabled
        self.jaw = min(max(self.jaw + velocity * self.gripper_speed, 0.0), JAW_OPEN)
        return tcp_target_to_action(env, self.desired, jaw_command(self.jaw))


def make_mapping(label: str, keys: list[str], env: KitbenchEnv, config, joint_action: JointAction, speed: float,
                 phone_scale: float, gripper_speed: float, turn_speed: float) -> Mapping:  # fmt: skip
    """The mapping for a device that names its actions `keys` on `env` (in its control mode), or one line saying
    why it cannot drive it; `joint_action` expresses a leader arm's joint targets in the env's mode."""
    given = set(keys)
    mapping: Mapping
    if set(PHONE_KEYS) <= given:
        from lerobot.teleoperators.phone.config_phone import PhoneConfig, PhoneOS

        platform = config.phone_os if isinstance(config, PhoneConfig) else PhoneOS.IOS
        mapping = PhoneMapping(env, platform, phone_scale, gripper_speed)
    elif set(DELTA_KEYS) | set(TURN_KEYS) <= given:
        mapping = TurnMapping(env, speed, turn_speed)
    elif set(DELTA_KEYS) <= given:
        mapping = DeltaMapping(env, speed)
    elif set(JointMapping.names(env)) <= given:
        mapping = JointMapping(env, joint_action)
    else:
        raise KitbenchError(
            f"{label} gives {', '.join(keys) or 'nothing'}, which drives no part of the {env.robot_uid}: a leader "
            f"arm must name its joints ({', '.join(JointMapping.names(env))}), an end-effector device give "
            f"{', '.join(DELTA_KEYS)} (gamepad, keyboard_ee) or a phone's pose (phone)"
        )
    if mapping.modes is not None and env.control_mode not in mapping.modes:
        raise KitbenchError(
            f"{label} ({mapping.kind}) cannot drive control_mode {env.control_mode}; valid choices: "
            f"{', '.join(mapping.modes)} (--control-mode)"
        )
    return mapping
