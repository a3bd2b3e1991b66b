"""Whether PhysX diverged in a step: a NaN or infinite pose or velocity of a dynamic body or of the robot, or a
dynamic body thrown faster than any play throws it (`TabletopEnv.step` ends the episode with the reason)."""

from __future__ import annotations

import numpy as np

# Faster than this (m/s), a task's object has been thrown by a solver failure rather than by the robot. The most
# violent play there is, uniform random absolute joint targets (pd_joint_pos), throws the peg at up to 10.1 m/s
# (15,000 steps; 1 step above 10 m/s) with a hand moving at up to 16 m/s; random play in the other control modes
# and the experts stay below 7 m/s, and an object falling off the table reaches 4.2 m/s at the floor. 25 m/s
# leaves 2.5x that margin; a diverged body goes to NaN or keeps accelerating. The robot's own links are not held
# to a speed: under random absolute targets its fingers reach 66 m/s (the gripper drive slamming them against
# their limits) without anything going wrong; they are checked for NaN and inf only.
MAX_BODY_SPEED = 25.0


class PhysicsWatch:
    """The bodies whose state tells whether PhysX diverged, collected once per scene (after the task built
    everything: AssemblingKits builds its kit as the episode starts): every dynamic actor (the task's objects) and
    the robot. A fixed-base articulation's link poses and velocities are functions of its joint positions and
    velocities, so finite joints mean finite links."""

    def __init__(self, scene, robot):
        self.robot = robot
        self.actors = [b for b in scene.physx_system.get_rigid_dynamic_components() if not b.kinematic]

    def fault(self) -> str | None:
        """What is wrong after a step, in one line, or None. One speed test per actor and one finiteness test
        over the robot's joints and the actors' poses and velocities: 11 us a step with AssemblingKits' one loose
        shape (20,000 calls), against ~0.8 ms for the step."""
        art = self.robot.articulation
        values = [art.get_qpos(), art.get_qvel()]
        for body in self.actors:
            velocity = body.linear_velocity
            # NaN and inf fail the comparison too, so this also tests the linear velocity for being finite
            if not velocity.dot(velocity) < MAX_BODY_SPEED**2:
                return self.describe()
            pose = body.entity_pose
            values += (pose.p, pose.q, body.angular_velocity)
        if np.isfinite(np.concatenate(values)).all():
            return None
        return self.describe()

    def describe(self) -> str:
        """One line naming every body that went wrong and how (the slow path, taken once per diverged episode)."""
        problems = []
        for body in self.actors:
            pose = body.entity_pose
            quantities = (
                ("position", pose.p),
                ("orientation", pose.q),
                ("linear velocity", body.linear_velocity),
                ("angular velocity", body.angular_velocity),
            )
            bad = [name for name, value in quantities if not np.isfinite(value).all()]
            speed = float(np.linalg.norm(body.linear_velocity))
            if bad:
                problems.append(f"{body.entity.name} has a non-finite {', '.join(bad)}")
            elif speed >= MAX_BODY_SPEED:
                problems.append(f"{body.entity.name} moves at {speed:.3g} m/s (limit {MAX_BODY_SPEED:g})")
        art = self.robot.articulation
        for name, value in (("joint positions", art.get_qpos()), ("joint velocities", art.get_qvel())):
            if not np.isfinite(value).all():
                problems.append(f"robot {self.robot.spec.uid} has non-finite {name}")
        return "; ".join(problems) or "a body's state is not finite"
