"""A robot's arm kinematics on MuJoCo, with inverse kinematics solved by mink.

The MuJoCo model is compiled from the same URDF SAPIEN simulates (`RobotSpec.mujoco_urdf`), so a pose solved
here is the pose the simulated robot reaches. Poses are in the robot's base frame (`RobotSpec.base_link`); the
joints outside the arm (fingers, a head or torso, a mobile base) are held where `set_body` last put them.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import mink
import mujoco
import numpy as np

from kitbench.geometry import pose_to_matrix
from kitbench.robots.spec import RobotSpec


@functools.cache
def _compiled(source: Callable[[], str]) -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(source())


def arm_model(spec: RobotSpec) -> mujoco.MjModel:
    """The robot's MuJoCo model, compiled once per process."""
    model = _compiled(spec.mujoco_urdf)  # variants of a robot share their model
    missing = [j for j in spec.arm_joints if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, j) < 0]
    if missing:  # pragma: no cover - guards the joint names we rely on
        raise RuntimeError(f"{spec.uid}: the MuJoCo model has no joint(s) {missing}")
    return model


def arm_joint_limits(spec: RobotSpec) -> np.ndarray:
    """(n, 2) position limits of the arm's joints (continuous joints: +-inf)."""
    model = arm_model(spec)
    limits = []
    for name in spec.arm_joints:
        j = model.joint(name)
        limits.append(j.range if j.limited else (-np.inf, np.inf))
    return np.array(limits, dtype=np.float64)


class ArmKinematics:
    """Forward kinematics and mink differential IK for a robot's TCP.

    IK minimises TCP pose error plus a light posture term (keeps solutions near the ready pose, away from the
    elbow flips a pure pose task drifts into), under joint position and velocity limits; every joint outside the
    arm is frozen.
    """

    def __init__(self, spec: RobotSpec, posture_cost: float = 1e-3, dt: float = 0.05, max_iterations: int = 30):
        self.spec = spec
        self.model = arm_model(spec)
        self.configuration = mink.Configuration(self.model)
        self.dt = dt
        self.max_iterations = max_iterations
        self._arm_adr = np.array([self.model.joint(n).qposadr[0] for n in spec.arm_joints])
        arm_dofs = {int(self.model.joint(n).dofadr[0]) for n in spec.arm_joints}
        self._q = self.configuration.q.copy()
        for name in spec.finger_joints:
            self._q[self.model.joint(name).qposadr[0]] = spec.finger_open
        self.set_body(spec.body_ready)
        self._offset = pose_to_matrix(*spec.tcp_offset)
        self._offset_inv = np.linalg.inv(self._offset)
        self.tcp_task = mink.FrameTask(
            spec.tcp_link, "body", position_cost=1.0, orientation_cost=spec.orientation_cost, lm_damping=1e-3
        )
        # the stall test weighs the orientation error as the task does, relative to the default weight (0.5): a
        # five-joint arm's unreachable part of an orientation must not hide progress on the position
        self._rot_weight = spec.orientation_cost / 0.5
        self.posture_task = mink.PostureTask(self.model, cost=posture_cost)
        q_ref = self._q.copy()
        q_ref[self._arm_adr] = spec.ready_arm_qpos
        self.posture_task.set_target(q_ref)
        velocity = dict(zip(spec.arm_joints, spec.arm_velocity_limits, strict=True))
        self.limits = [mink.ConfigurationLimit(self.model), mink.VelocityLimit(self.model, velocity)]
        frozen = [d for d in range(self.model.nv) if d not in arm_dofs]
        self.constraints = [mink.DofFreezingTask(self.model, dof_indices=frozen)] if frozen else []

    def set_body(self, body_qpos) -> None:
        """Where the joints outside the arm and fingers stand (a torso's height changes where the arm reaches)."""
        for name, value in zip(self.spec.body_joints, body_qpos, strict=True):
            self._q[self.model.joint(name).qposadr[0]] = value

    def _load(self, arm_qpos) -> None:
        self._q[self._arm_adr] = arm_qpos
        self.configuration.update(self._q)

    def tcp_pose(self, arm_qpos) -> np.ndarray:
        """4x4 TCP pose in the base frame."""
        self._load(arm_qpos)
        body = self.configuration.get_transform_frame_to_world(self.spec.tcp_link, "body").as_matrix()
        return body @ self._offset

    def solve(
        self,
        target: np.ndarray,
        arm_qpos_init,
        pos_tol: float = 1e-4,
        rot_tol: float = 1e-3,
        max_iterations: int | None = None,
    ) -> tuple[np.ndarray, bool]:
        """Arm joint positions reaching the 4x4 TCP target from `arm_qpos_init`; returns (qpos, converged)."""
        self._load(arm_qpos_init)
        self.tcp_task.set_target(mink.SE3.from_matrix(target @ self._offset_inv))
        tasks = [self.tcp_task, self.posture_task]
        converged = False
        previous = np.inf
        for _ in range(max_iterations or self.max_iterations):
            err = self.tcp_task.compute_error(self.configuration)
            pos_err, rot_err = float(np.linalg.norm(err[:3])), float(np.linalg.norm(err[3:]))
            if pos_err < pos_tol and rot_err < rot_tol:
                converged = True
                break
            error = pos_err + self._rot_weight * rot_err
            if error > 0.9 * previous:  # stalled (a limit or the posture term): more is wasted
                break
            previous = error
            velocity = mink.solve_ik(
                self.configuration,
                tasks,
                self.dt,
                "daqp",
                damping=1e-6,
                limits=self.limits,
                constraints=self.constraints,
            )
            self.configuration.integrate_inplace(velocity, self.dt)
        return self.configuration.q[self._arm_adr].copy(), converged
