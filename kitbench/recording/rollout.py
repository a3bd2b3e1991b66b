"""Run one episode with a policy and keep everything a dataset or a log needs, frame by frame.

A frame holds the observation at step t, the action taken at t, and what that action led to (`next.*`).
The whole episode stays in memory until it ends, so an interrupted run never leaves half an episode behind.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from kitbench.geometry import matrix_to_quat
from kitbench.recording.mcap_log import EpisodeMcap


@dataclass
class EpisodeRecord:
    seed: int
    task: str  # the natural-language instruction
    frames: list[dict] = field(default_factory=list)
    success: bool = False
    first_success: int | None = None  # step index of the first successful frame
    config: dict = field(default_factory=dict)
    physics_error: str | None = None  # the simulation failed at the last step (`info["physics_error"]`)

    @property
    def length(self) -> int:
        return len(self.frames)


def commanded_tcp_pose(u) -> np.ndarray:
    """The TCP pose the controller is driving to, base frame [x, y, z, qw, qx, qy, qz], in every mode."""
    controller = u.controller
    target = controller.tcp_target
    if target is None:
        target = controller.kinematics.tcp_pose(controller.joint_target)
    return np.concatenate([target[:3, 3], matrix_to_quat(target[:3, :3])]).astype(np.float32)


def task_config(u) -> dict:
    return {"control_mode": u.control_mode, "obs_mode": u.obs_mode, **u.episode_config()}


def _world_frames(u) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The robot's links and the task's tracked frames (objects, goals), world poses."""
    frames = {link.name: (link.entity_pose.p, link.entity_pose.q) for link in u.robot.articulation.links}
    frames.update(u.tracked_frames())
    return frames


def run_episode(env, policy, seed: int, mcap_path: Path | None = None) -> EpisodeRecord:
    u = env.unwrapped
    obs, info = env.reset(seed=seed)
    policy.reset(env, seed, obs, info)
    record = EpisodeRecord(seed=seed, task=u.task_description(), config=task_config(u))
    log = EpisodeMcap(mcap_path, u.camera_names) if mcap_path is not None else None
    joint_names = [j.name for j in u.robot.articulation.active_joints]
    dt_ns = round(1e9 * u.control_timestep)
    try:
        step = 0
        while True:
            frame = {
                "observation.state": u.robot_state(),
                "observation.environment_state": u.environment_state(),
            }
            images = {}
            if u.camera_names:
                images = {c: obs["sensor_data"][c]["rgb"] for c in u.camera_names}
                for c, rgb in images.items():
                    frame[f"observation.images.{c}"] = rgb
            action = np.asarray(policy.act(obs), dtype=np.float32)
            obs, reward, terminated, truncated, info = env.step(action)
            frame["action"] = np.clip(action, u.action_space.low, u.action_space.high)
            frame["commanded_ee_pose"] = commanded_tcp_pose(u)
            frame["next.reward"] = np.array([reward], dtype=np.float32)
            frame["next.done"] = np.array([terminated or truncated], dtype=bool)
            frame["next.success"] = np.array([bool(info["success"])], dtype=bool)
            record.frames.append(frame)
            if log is not None:
                log.log_step(
                    (step + 1) * dt_ns,
                    frames=_world_frames(u),
                    joint_names=joint_names,
                    qpos=u.robot.qpos(),
                    qvel=u.robot.qvel(),
                    images={c: obs["sensor_data"][c]["rgb"] for c in u.camera_names},
                    action=frame["action"],
                    reward=reward,
                    success=bool(info["success"]),
                    phase=getattr(policy, "phase", None) or "policy",
                    tcp_target=getattr(policy, "tcp_target", None),
                )
            if info["success"] and record.first_success is None:
                record.first_success = step
            step += 1
            if terminated or truncated:
                break
    finally:
        if log is not None:
            log.close()
    record.physics_error = info.get("physics_error")
    record.success = record.first_success is not None
    return record
