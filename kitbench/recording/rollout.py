"""One recorded episode: the rollout loop (`kitbench.rollout`) with the hooks that keep what a dataset or a log
needs, frame by frame.

A frame holds the observation at step t, the action taken at t, and what that action led to (`next.*`). The whole
episode stays in memory until it ends, so an interrupted run never leaves half an episode behind.

The hooks (`run_episode` composes them): `Frames` (the dataset's frames), `McapLog` (the episode's MCAP log),
`ExpertLabels` (DAgger, `kitbench record --label expert`: a second policy, reset on the same episode, is asked at
every state the acting policy reaches; its answer is the frame's `action`), `Noise` (`--action-noise`: until the
first success the robot executes the policy's action plus seeded noise, confined to `noise_phases` of the policy;
`executed_action` is what the robot got) and the loop's `SettleAfterSuccess` (`--settle-steps`: the episode goes on
this many steps after its first success, so the data shows the policy holding or releasing a finished task).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

import numpy as np

from kitbench.envs.features import observation_frame
from kitbench.envs.interface import KitbenchEnv, as_kitbench
from kitbench.envs.modes import POINTCLOUD
from kitbench.envs.pointcloud import DEFAULT_POINTS, PointSampler
from kitbench.geometry import matrix_to_quat
from kitbench.policies.base import label_of, phase_of, tcp_target_of
from kitbench.recording.mcap_log import EpisodeMcap
from kitbench.recording.noise import ActionNoise
from kitbench.recording.scene_geometry import Body, optical_frame, scene_bodies, scene_update
from kitbench.rollout import Control, Episode, Hook, OneEpisode, SettleAfterSuccess, Step, clipped, run


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
    control: Control | None = None  # a person's request that ended it (teleoperation: re-record, stop)
    teleop: dict | None = None  # a person's episode: how it ended (key, success, limit), clip and rate-limit counts

    @property
    def length(self) -> int:
        return len(self.frames)


def commanded_tcp_pose(env: KitbenchEnv) -> np.ndarray:
    """The TCP pose the controller is driving to, base frame [x, y, z, qw, qx, qy, qz], in every mode."""
    controller = env.controller
    target = controller.tcp_target
    if target is None:
        target = controller.kinematics.tcp_pose(controller.joint_target)
    return np.concatenate([target[:3, 3], matrix_to_quat(target[:3, :3])]).astype(np.float32)


def task_config(env: KitbenchEnv) -> dict:
    return {"control_mode": env.control_mode, "obs_mode": env.obs_mode, **env.episode_config()}


class Frames(Hook):
    """The dataset's frames of the episode, into `record`. `labels()`: this step's label, when something other than
    the acting policy labels the frames (None: the policy's own action)."""

    def __init__(self, record: EpisodeRecord, points: int, labels: Callable[[], np.ndarray | None]):
        self.record, self.points, self.labels = record, points, labels
        self._frame: dict = {}

    def on_reset(self, episode: Episode) -> None:
        env = as_kitbench(episode.env)
        self.record.task, self.record.config = env.task_description(), task_config(env)
        self.sampler = PointSampler(self.points, episode.seed)

    def before_act(self, episode: Episode) -> None:
        self._frame = observation_frame(episode.env, episode.obs, self.sampler)

    def after_step(self, episode: Episode, step: Step) -> None:
        frame = self._frame
        label = self.labels()
        frame["action"] = step.action if label is None else label
        frame["executed_action"] = step.executed
        frame["commanded_ee_pose"] = commanded_tcp_pose(as_kitbench(episode.env))
        frame["next.reward"] = np.array([step.reward], dtype=np.float32)
        frame["next.done"] = np.array([step.terminated or step.truncated], dtype=bool)
        frame["next.success"] = np.array([bool(step.info["success"])], dtype=bool)
        self.record.frames.append(frame)

    def on_end(self, episode: Episode) -> None:
        self.record.first_success = episode.first_success
        self.record.success = episode.success
        self.record.physics_error = episode.info.get("physics_error")
        self.record.control = episode.control


class ExpertLabels(Hook):
    """DAgger: `labeler` is asked first at every state (before the acting policy, the state untouched); its
    answer labels the frame."""

    def __init__(self, labeler):
        self.labeler = labeler
        self.label: np.ndarray | None = None

    def on_reset(self, episode: Episode) -> None:
        self.labeler.reset(episode.env, episode.seed, episode.obs, episode.info)

    def before_act(self, episode: Episode) -> None:
        self.label = clipped(episode.env, self.labeler.act(episode.obs))


class Noise(Hook):
    """Until the first success, the robot executes the action plus seeded noise (`recording.noise`), in the
    policy's `phases` only when given. None once the task is done: settling shows the finished state held, which
    LiftPegUpright's 2 mm height tolerance does not survive at 0.01 rad of joint noise (1 of 20 episodes stayed a
    success)."""

    def __init__(self, scale: float, phases: tuple[str, ...] | None, policy):
        self.scale, self.phases, self.policy = scale, phases, policy

    def on_reset(self, episode: Episode) -> None:
        self.noise = ActionNoise.for_env(as_kitbench(episode.env), self.scale, episode.seed)

    def executed(self, episode: Episode, action: np.ndarray) -> np.ndarray:
        noisy = episode.first_success is None
        if noisy and self.phases is not None:
            noisy = phase_of(self.policy) in self.phases
        return self.noise.perturb(action) if noisy else action


def _world_frames(env: KitbenchEnv, bodies: list[Body], obs) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """World poses: the robot's links, the task's tracked frames (objects, goals), every body the scene
    geometry is attached to and each camera's optical frame. Static bodies (the table, a kit's seated shapes) are
    logged every step like the rest, so that any one `/tf` message places the whole scene: ~170 bytes for a
    LiftPegUpright episode's table."""
    frames = {link.name: (link.entity_pose.p, link.entity_pose.q) for link in env.robot.articulation.links}
    frames.update(env.tracked_frames())
    for body in bodies:
        frames.setdefault(body.frame, body.pose())
    for c in env.camera_names:
        frames[c] = optical_frame(obs["sensor_param"][c]["extrinsic_cv"])
    return frames


class McapLog(Hook):
    """The episode's MCAP log, into `target` (a path or a binary stream): the scene and the cameras' calibrations
    at time 0, the state each step (and after the last), the executed action with the policy's phase and TCP
    target, and each step's reward and success."""

    def __init__(self, target: Path | BinaryIO, policy):
        self.target, self.policy = target, policy
        self.log: EpisodeMcap | None = None

    def on_reset(self, episode: Episode) -> None:
        env = as_kitbench(episode.env)
        pointcloud = env.obs_mode == POINTCLOUD  # its cameras' textures travel in the cloud, not as images
        textures = frozenset() if pointcloud else env.camera_textures
        ids = env.segmentation_id_map if "segmentation" in textures else None
        self.env = env
        self.log = EpisodeMcap(self.target, env.camera_names, textures, ids, pointcloud)
        self.joint_names = [j.name for j in env.robot.articulation.active_joints]
        self.dt_ns = round(1e9 * env.control_timestep)
        self.bodies = scene_bodies(env.scene)
        self.log.log_scene(0, scene_update(self.bodies))
        for spec in env.camera_specs():
            if spec.name in env.camera_names:
                intrinsic = episode.obs["sensor_param"][spec.name]["intrinsic_cv"]
                self.log.log_calibration(0, spec.name, intrinsic, spec.width, spec.height)

    def _state(self, episode: Episode) -> None:
        assert self.log is not None
        sensed = episode.obs if isinstance(episode.obs, dict) else {}  # state observations are a flat vector
        self.log.log_state(
            episode.steps * self.dt_ns,
            frames=_world_frames(self.env, self.bodies, episode.obs),
            joint_names=self.joint_names,
            qpos=self.env.robot.qpos(),
            qvel=self.env.robot.qvel(),
            cameras=sensed.get("sensor_data", {}),
            pointcloud=sensed.get("pointcloud"),
        )

    def before_act(self, episode: Episode) -> None:
        self._state(episode)

    def on_action(self, episode: Episode, action: np.ndarray, executed: np.ndarray) -> None:
        assert self.log is not None
        phase = phase_of(self.policy) or "policy"
        self.log.log_action(episode.steps * self.dt_ns, executed, phase, tcp_target_of(self.policy))

    def after_step(self, episode: Episode, step: Step) -> None:
        assert self.log is not None
        self.log.log_outcome(episode.steps * self.dt_ns, step.reward, bool(step.info["success"]))

    def on_end(self, episode: Episode) -> None:
        self._state(episode)  # the state the last action led to (the dataset has no frame for it)
        self.close()

    def close(self) -> None:
        if self.log is not None:
            self.log.close()
            self.log = None


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
    hooks: tuple[Hook, ...] = (),
) -> EpisodeRecord:
    """Run `policy` on `seed` to the end and keep its dataset frames, logging to `mcap` when given. `points`: the
    point cloud's size per frame (obs_mode pointcloud), drawn with the episode's seed; `labeler`: the policy whose
    action at each state is stored as `action` (default: `policy`'s own, or its `label` when it labels itself, as a
    conversion's replay does); `hooks`: more, after the recording's (a score, as `kitbench eval` keeps one)."""
    env = as_kitbench(env)
    record = EpisodeRecord(seed=seed, task="")
    labels: ExpertLabels | None = None if labeler is None else ExpertLabels(labeler)

    def label() -> np.ndarray | None:
        if labels is not None:
            return labels.label
        own = label_of(policy)
        return None if own is None else clipped(env, own)

    chain: list[Hook] = [Frames(record, points, label)]
    log = McapLog(mcap, policy) if mcap is not None else None
    if log is not None:
        chain.append(log)
    if labels is not None:
        chain.append(labels)
    if action_noise > 0:
        chain.append(Noise(action_noise, noise_phases, policy))
    chain += [SettleAfterSuccess(settle_steps), *hooks]
    try:
        (ran,) = run([env], [seed], OneEpisode(policy), lambda _: chain)
    finally:
        if log is not None:
            log.close()
    record.teleop = ran.teleop
    return record
