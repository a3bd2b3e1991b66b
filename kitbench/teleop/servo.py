"""A device's action held to the follower's joint speeds (`ServoLimit`), whatever the mapping and the control
mode: the joint targets the action leads to (the controller's `preview`: a leader's joints, the IK of an
end-effector target) are rate-limited (`kitbench.teleop.limits`), and where a joint was limited the action is
expressed again from the limited targets (`joint_target_to_action`). Limited steps are counted per episode."""

from __future__ import annotations

import numpy as np

from kitbench.envs.interface import KitbenchEnv
from kitbench.teleop.limits import JointRateLimiter
from kitbench.teleop.mapping import JointAction


class ServoLimit:
    def __init__(self, env: KitbenchEnv, joint_action: JointAction):
        self.limiter = JointRateLimiter.for_robot(env.robot_spec, env.control_timestep)
        self.joint_action = joint_action

    @property
    def limited_steps(self) -> int:
        """Steps of this episode where a joint was limited."""
        return self.limiter.limited_steps

    def reset(self, env: KitbenchEnv) -> None:
        """A new episode: the servos' last target is the controller's (the arm at rest where it was reset)."""
        self.limiter.reset(env.controller.joint_target)

    def __call__(self, env: KitbenchEnv, action: np.ndarray) -> np.ndarray:
        """`action` (the env's, in its mode), with the arm's targets rate-limited."""
        sim = env.action_to_sim(np.asarray(action))
        n_arm = env.controller.physical_space.shape[0] - 1
        requested = env.controller.preview(sim[:n_arm], env.robot.arm_qpos())
        commanded, limited = self.limiter(requested)
        if not limited:
            return action
        return self.joint_action(env, commanded, float(sim[n_arm])).astype(np.asarray(action).dtype)
