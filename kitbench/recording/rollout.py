"""Run one episode with a policy and keep everything a dataset or a log needs, frame by frame.

A frame holds the observation at step t, the action taken at t, and what that action led to (`next.*`).
The whole episode stays in memory until it ends, so an interrupted run never leaves half an episode behind.

Two options make demonstrations for learning (`kitbench record --action-noise / --settle-steps`):
- `action_noise`: until the first success, the robot executes the policy's action plus seeded noise
  (`noise.ActionNoise`); the frame's `action` stays the policy's own, `executed_action` is what the robot got.
  `noise_phases` confines the noise to the steps the policy plays in those phases (its `phase` after `act`).
- `settle_steps`: the episode goes on this many steps after its first success (the task ends an episode at
  success), so the data shows the policy holding or releasing a finished task instead of stopping mid-motion.

`labeler` (`kitbench record --label expert`, DAgger): a second policy, reset on the same episode, is asked at every
state the acting policy reaches; its answer is the frame's `action`, and `executed_action` what the acting policy
did (plus any noise).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

import numpy as np

from kitbench.envs.features import observation_frame
from kitbench.envs.modes import POINTCLOUD
from kitbench.envs.pointcloud import DEFAULT_POINTS, PointSampler
from kitbench.geometry import matrix_to_quat
from kitbench.recording.mcap_log import EpisodeMcap
from kitbench.recording.noise import ActionNoise
from kitbench.recording.scene_geometry import Body, optical_frame, scene_bodies, scene_update


@dataclass
class EpisodeRecord:
    seed: int
    task: str  # the natural-language instruction
    frames: list[dict] = field(default_factory=list)
    success: bool = False
    first_success: int | None = None  # step index of the first successful frame
    config: dict = field(default_factory=dict)
    physics_error: str | None = None  # the simulation failed at the last step (`info["physics_error"]`)
    rejected: str | None = None  # why the episode is not to be stored although it ran (a conversion that diverged)

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


def _clipped(u, action) -> np.ndarray:
    return np.clip(np.asarray(action, dtype=np.float32), u.action_space.low, u.action_space.high)


def task_config(u) -> dict:
    return {"control_mode": u.control_mode, "obs_mode": u.obs_mode, **u.episode_config()}


def _world_frames(u, bodies: list[Body], obs) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """World poses: the robot's links, the task's tracked frames (objects, goals), every body the scene
    geometry is attached to and each camera's optical frame. Static bodies (the table, a kit's seated shapes) are
    logged every step like the rest, so that any one `/tf` message places the whole scene: ~170 bytes for a
    LiftPegUpright episode's table."""
    frames = {link.name: (link.entity_pose.p, link.entity_pose.q) for link in u.robot.articulation.links}
    frames.update(u.tracked_frames())
    for body in bodies:
        frames.setdefault(body.frame, body.pose())
    for c in u.camera_names:
        frames[c] = optical_frame(obs["sensor_param"][c]["extrinsic_cv"])
    return frames


def _log_scene(log: EpisodeMcap, u, obs) -> list[Body]:
    """At time 0: the geometry of the scene this episode built, and each camera's calibration."""
    bodies = scene_bodies(u.scene)
    log.log_scene(0, scene_update(bodies))
    for spec in u.camera_specs():
        if spec.name in u.camera_names:
            log.log_calibration(0, spec.name, obs["sensor_param"][spec.name]["intrinsic_cv"], spec.width, spec.height)
    return bodies


def _log_state(log: EpisodeMcap, u, t_ns: int, joint_names, bodies: list[Body], obs) -> None:
    sensed = obs if isinstance(obs, dict) else {}  # state observations are a flat vector
    log.log_state(
        t_ns,
        frames=_world_frames(u, bodies, obs),
        joint_names=joint_names,
        qpos=u.robot.qpos(),
        qvel=u.robot.qvel(),
        cameras=sensed.get("sensor_data", {}),
        pointcloud=sensed.get("pointcloud"),
    )


def run_episode(
    env,
    policy,
    seed: int,
    mcap: Path | BinaryIO | None = None,
    action_noise: float = 0.0,
    settle_steps: int = 0,
    noise_phases: tuple[str, ...] | None = None,
    points: int = DEFAULT_POINTS,
    labeler=None,
    observer=None,
) -> EpisodeRecord:
    """Run `policy` on `seed` to the end, logging to `mcap` (a path or a binary stream) when given. `points`: the
    point cloud's size per frame (obs_mode pointcloud), drawn with the episode's seed; `labeler`: the policy whose
    action at each state is stored as `action` (default: `policy`'s own); `observer`: told every step's outcome
    (`observer.step(reward, terminated, truncated, info)`, as `kitbench eval` scores an episode it also stores)."""
    u = env.unwrapped
    obs, info = env.reset(seed=seed)
    policy.reset(env, seed, obs, info)
    if labeler is not None:
        labeler.reset(env, seed, obs, info)
    noise = ActionNoise.for_env(env, action_noise, seed) if action_noise > 0 else None
    record = EpisodeRecord(seed=seed, task=u.task_description(), config=task_config(u))
    log = None
    if mcap is not None:
        pointcloud = u.obs_mode == POINTCLOUD  # its cameras' textures travel in the cloud, not as images
        textures = frozenset() if pointcloud else u.camera_textures
        ids = u.segmentation_id_map if "segmentation" in textures else None
        log = EpisodeMcap(mcap, u.camera_names, textures, ids, pointcloud)
    sampler = PointSampler(points, seed)
    joint_names = [j.name for j in u.robot.articulation.active_joints]
    dt_ns = round(1e9 * u.control_timestep)
    try:
        bodies = _log_scene(log, u, obs) if log is not None else []
        step = 0
        while True:
            frame = observation_frame(env, obs, sampler)
            if log is not None:
                _log_state(log, u, step * dt_ns, joint_names, bodies, obs)
            label = None if labeler is None else _clipped(u, labeler.act(obs))  # asked first: the state is untouched
            action = _clipped(u, policy.act(obs))
            # no noise once the task is done: settling shows the finished state held, which LiftPegUpright's
            # 2 mm height tolerance does not survive at 0.01 rad of joint noise (1 of 20 episodes stayed a success)
            noisy = noise is not None and record.first_success is None
            if noisy and noise_phases is not None:
                noisy = getattr(policy, "phase", None) in noise_phases
            executed = noise.perturb(action) if noisy and noise is not None else action
            if log is not None:
                phase = getattr(policy, "phase", None) or "policy"
                log.log_action(step * dt_ns, executed, phase, getattr(policy, "tcp_target", None))
            obs, reward, terminated, truncated, info = env.step(executed)
            if observer is not None:
                observer.step(reward, terminated, truncated, info)
            if info["success"] and record.first_success is None:
                record.first_success = step
            if record.first_success is not None:
                # the task ends an episode at its first success; settling ends it settle_steps later (or when
                # time runs out), whatever the task's state by then
                terminated = step - record.first_success >= settle_steps
            frame["action"] = action if label is None else label
            frame["executed_action"] = executed
            frame["commanded_ee_pose"] = commanded_tcp_pose(u)
            frame["next.reward"] = np.array([reward], dtype=np.float32)
            frame["next.done"] = np.array([terminated or truncated], dtype=bool)
            frame["next.success"] = np.array([bool(info["success"])], dtype=bool)
            record.frames.append(frame)
            if log is not None:
                log.log_outcome((step + 1) * dt_ns, reward, bool(info["success"]))
            step += 1
            if terminated or truncated:
                break
        if log is not None:  # the state the last action led to (the dataset has no frame for it)
            _log_state(log, u, step * dt_ns, joint_names, bodies, obs)
    finally:
        if log is not None:
            log.close()
    record.physics_error = info.get("physics_error")
    record.success = record.first_success is not None
    return record
