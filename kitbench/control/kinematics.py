"""Panda kinematics on MuJoCo, with inverse kinematics solved by mink.

The MuJoCo model is compiled from the same URDF SAPIEN simulates, so a pose solved here is the pose the
simulated robot reaches. Poses are in the robot's base frame.
"""

from __future__ import annotations

import functools

import mink
import mujoco
import numpy as np

from kitbench.robots.assets import panda_mujoco_urdf
from kitbench.robots.panda import ARM_JOINTS, READY_ARM_QPOS, TCP_LINK

ARM_VELOCITY_LIMITS = {
    "panda_joint1": 2.175,
    "panda_joint2": 2.175,
    "panda_joint3": 2.175,
    "panda_joint4": 2.175,
    "panda_joint5": 2.61,
    "panda_joint6": 2.61,
    "panda_joint7": 2.61,
}


@functools.cache
def panda_model() -> mujoco.MjModel:
    model = mujoco.MjModel.from_xml_string(panda_mujoco_urdf())
    names = [model.joint(i).name for i in range(model.njnt)]
    if names[:7] != list(ARM_JOINTS):  # pragma: no cover - guards the joint order we rely on
        raise RuntimeError(f"unexpected MuJoCo joint order {names}")
    return model


class PandaKinematics:
    """Forward kinematics and mink differential IK for the Panda's TCP.

    IK minimises TCP pose error plus a light posture term (keeps solutions near the ready pose, away from
    the elbow flips a pure pose task drifts into), under joint position and velocity limits; fingers are frozen.
    """

    def __init__(self, posture_cost: float = 1e-3, dt: float = 0.05, max_iterations: int = 30):
        self.model = panda_model()
        self.configuration = mink.Configuration(self.model)
        self.dt = dt
        self.max_iterations = max_iterations
        self.tcp_task = mink.FrameTask(TCP_LINK, "body", position_cost=1.0, orientation_cost=0.5, lm_damping=1e-3)
        self.posture_task = mink.PostureTask(self.model, cost=posture_cost)
        q_ref = np.zeros(self.model.nq)
        q_ref[:7] = READY_ARM_QPOS
        q_ref[7:9] = 0.04
        self.posture_task.set_target(q_ref)
        self.limits = [mink.ConfigurationLimit(self.model), mink.VelocityLimit(self.model, ARM_VELOCITY_LIMITS)]
        self.constraints = [mink.DofFreezingTask(self.model, dof_indices=[7, 8])]
        self._body_id = self.model.body(TCP_LINK).id
        self._q = np.zeros(self.model.nq)

    def _load(self, arm_qpos) -> None:
        self._q[:7] = arm_qpos
        self._q[7:9] = 0.04
        self.configuration.update(self._q)

    def tcp_pose(self, arm_qpos) -> np.ndarray:
        """4x4 TCP pose in the base frame."""
        self._load(arm_qpos)
        return self.configuration.get_transform_frame_to_world(TCP_LINK, "body").as_matrix()

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
        self.tcp_task.set_target(mink.SE3.from_matrix(target))
        tasks = [self.tcp_task, self.posture_task]
        converged = False
        previous = np.inf
        for _ in range(max_iterations or self.max_iterations):
            err = self.tcp_task.compute_error(self.configuration)
            pos_err, rot_err = float(np.linalg.norm(err[:3])), float(np.linalg.norm(err[3:]))
            if pos_err < pos_tol and rot_err < rot_tol:
                converged = True
                break
            if pos_err + rot_err > 0.9 * previous:  # stalled (a limit or the posture term): more is wasted
                break
            previous = pos_err + rot_err
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
        return self.configuration.q[:7].copy(), converged
