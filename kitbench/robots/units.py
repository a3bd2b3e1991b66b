"""`JointUnits`: how a robot's actions and LeRobot `observation.state` express its joints and gripper.

Inside the simulation joints are radians and the gripper action is a command from -1 (closed) to 1 (open)
(`kitbench.robots.spec`). `SI` shows them so. `SO_FOLLOWER` shows them as LeRobot's SO follower reports a real
SO-100/SO-101 (`lerobot/robots/so_follower`, `use_degrees`): the body joints in degrees, the jaw's position from
0 to 100 over its range (LeRobot's `RANGE_0_100`), each named `<motor>.pos`, so that a recording has the real
arm's layout. The env converts at its boundary (`TabletopEnv.action_to_sim`, `action_from_sim`, `robot_state`).

`SI` robots' actions are ManiSkill's (delta modes normalised to [-1, 1]); `SO_FOLLOWER`'s joint actions (absolute
and deltas) take the joint unit, and its end-effector actions are ManiSkill's, having no motor to speak for. A
robot in `SO_FOLLOWER` units commands its jaw's position (0..100) in every mode, as the
real arm's leader does; its body joints and base, if it had any, would stay in SI. Which modes are joint modes
the controllers say (`Controller.frame`): the callers pass `joints`, as this package sits below them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from kitbench.robots.spec import RobotSpec


@dataclass(frozen=True)
class JointUnits:
    name: str
    per_radian: float = 1.0  # joint values (positions and deltas) per radian
    gripper_percent: bool = False  # the gripper as its joint's position, 0 (closed) .. 100 (open) over its range
    suffix: str = ""  # appended to each joint's name (LeRobot's motor features: ".pos")
    # Whether joint-mode actions are in these units (a real arm's degrees) rather than ManiSkill's form (the delta
    # modes normalised to [-1, 1]: `kitbench.control.controllers`); end-effector modes are always ManiSkill's.
    joint_actions: bool = False
    # What a dataset card says `observation.state` and `action` hold in these units (None: kitbench's SI wording).
    state_text: str | None = None
    action_text: str | None = None

    # -- names -----------------------------------------------------------------------------------------
    def state_names(self, spec: RobotSpec) -> tuple[str, ...]:
        """LeRobot's `observation.state`: the arm's joints, the gripper, body joints, base x, y, yaw."""
        gripper = f"{self._jaw(spec)}{self.suffix}" if self.gripper_percent else "gripper_opening"
        names = (*self.joint_names(spec), gripper, *spec.body_joints)
        return (*names, "base_x", "base_y", "base_yaw") if spec.has_base else names

    def joint_names(self, spec: RobotSpec) -> list[str]:
        """The arm's joints as these units name them (a joint mode's action names build on them)."""
        return [f"{j}{self.suffix}" for j in spec.arm_joints]

    def gripper_action_name(self, spec: RobotSpec) -> str:
        return f"{self._jaw(spec)}{self.suffix}" if self.gripper_percent else "gripper"

    def expresses(self, joints: bool) -> bool:
        """Whether the arm part of a mode's action is in these units (else in ManiSkill's form); `joints`: whether
        the mode's arm part is the arm's joints."""
        return self.joint_actions and joints

    # -- values ----------------------------------------------------------------------------------------
    def state(self, spec: RobotSpec, vector: np.ndarray) -> np.ndarray:
        """`Robot.state_vector` (radians, gripper opening) in these units."""
        out = np.array(vector, dtype=np.float64)
        n = len(spec.arm_joints)
        out[:n] *= self.per_radian
        if self.gripper_percent:
            low, high = self._jaw_range(spec)
            out[n] = 100.0 * (out[n] - low) / (high - low)
        return out

    def state_scales(self, spec: RobotSpec) -> list[float]:
        """Each `observation.state` entry's units per SI unit (radian or metre): what a threshold set in SI, such
        as a dataset card's for joints held still, is multiplied by."""
        n = len(spec.arm_joints)
        scales = [1.0] * len(self.state_names(spec))
        scales[:n] = [self.per_radian] * n
        if self.gripper_percent:
            low, high = self._jaw_range(spec)
            scales[n] = 100.0 / abs(high - low)
        return scales

    def action_to_sim(self, spec: RobotSpec, joints: bool, n_arm: int, action: np.ndarray) -> np.ndarray:
        """An action in these units to the simulation's (radians, gripper command -1..1)."""
        if self is SI:
            return action
        out = np.array(action, dtype=np.float64)
        if joints:
            out[:n_arm] /= self.per_radian
        if self.gripper_percent:  # 0..100 spans the command's closed (-1) .. open (1): the jaw's range is both's
            out[n_arm] = out[n_arm] / 50.0 - 1.0
        return out

    def action_from_sim(self, spec: RobotSpec, joints: bool, n_arm: int, action: np.ndarray) -> np.ndarray:
        """An action in the simulation's units to these (`action_to_sim`'s inverse)."""
        if self is SI:
            return action
        out = np.array(action, dtype=np.float64)
        if joints:
            out[:n_arm] *= self.per_radian
        if self.gripper_percent:  # unclipped: a caller may ask how far out of the box an action lies
            out[n_arm] = 50.0 * (out[n_arm] + 1.0)
        return out.astype(np.asarray(action).dtype)

    def action_bounds(self, spec: RobotSpec, joints: bool, n_arm: int, low, high) -> tuple[np.ndarray, np.ndarray]:
        """The action box of a mode (the controller's, in the simulation's units) in these units."""
        lo, hi = np.array(low, dtype=np.float64), np.array(high, dtype=np.float64)
        if joints:
            lo[:n_arm] *= self.per_radian
            hi[:n_arm] *= self.per_radian
        if self.gripper_percent:
            lo[n_arm], hi[n_arm] = 0.0, 100.0
        return lo.astype(np.float32), hi.astype(np.float32)

    def joint_unit(self, joints: bool) -> float:
        """Action units per radian of a mode's arm part (1 for end-effector modes)."""
        return self.per_radian if joints else 1.0

    # -- the jaw ---------------------------------------------------------------------------------------
    @staticmethod
    def _jaw(spec: RobotSpec) -> str:
        if len(spec.finger_joints) != 1:
            raise ValueError(f"{spec.uid}: a gripper in percent needs one jaw joint, not {spec.finger_joints}")
        return spec.finger_joints[0]

    @staticmethod
    def _jaw_range(spec: RobotSpec) -> tuple[float, float]:
        """The jaw joint's range, closed to open (the ends of the 0..100 scale)."""
        return spec.finger_closed, spec.finger_open


SI = JointUnits("si")
SO_FOLLOWER = JointUnits(
    "so_follower",
    per_radian=180.0 / math.pi,
    gripper_percent=True,
    joint_actions=True,
    suffix=".pos",
    state_text="the arm's motors as LeRobot's SO follower reports them: joints in degrees, `gripper.pos` 0 (closed) "
    "to 100 (open)",
    action_text="the policy's action in the control mode, in the SO follower's units (joint targets or deltas in "
    "degrees; `gripper.pos` 0 closed .. 100 open, absolute in every mode)",
)
