"""Scripted motions for physics tests: follow TCP waypoints with IK-solved `pd_joint_pos` actions."""

from __future__ import annotations

import numpy as np

from kitbench.control.kinematics import ArmKinematics
from kitbench.geometry import pose_to_matrix


class WaypointFollower:
    def __init__(self, env):
        self.env = env.unwrapped
        assert self.env.control_mode == "pd_joint_pos"
        self.kin = ArmKinematics(self.env.robot_spec)
        self.base = pose_to_matrix(self.env.robot.base_pose.p, self.env.robot.base_pose.q)
        self.base_inv = np.linalg.inv(self.base)
        self.last = None

    def tcp_world(self) -> np.ndarray:
        p = self.env.robot.tcp_pose()
        return pose_to_matrix(p.p, p.q)

    def move(self, target_world: np.ndarray, gripper: float, steps: int, settle: int = 3):
        """Interpolate from the current TCP pose to the target in `steps` control steps, then hold."""
        from scipy.spatial.transform import Rotation, Slerp

        start = self.tcp_world()
        rots = Rotation.from_matrix(np.stack([start[:3, :3], target_world[:3, :3]]))
        slerp = Slerp([0, 1], rots)
        q = self.env.robot.qpos()[:7]
        out = None
        for i in range(1, steps + settle + 1):
            s = min(1.0, i / steps)
            t = np.eye(4)
            t[:3, :3] = slerp([s]).as_matrix()[0]
            t[:3, 3] = (1 - s) * start[:3, 3] + s * target_world[:3, 3]
            q, _ = self.kin.solve(self.base_inv @ t, q)
            out = self.env.step(np.append(q, gripper).astype(np.float32))
        return out
