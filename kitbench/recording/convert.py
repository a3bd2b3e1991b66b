"""`kitbench convert SRC --out DST`: a recording re-simulated into other observations or another action space.

Each episode of SRC is played again from its seed (`meta/kitbench_episodes.jsonl`) with the actions its robot
executed (`executed_action`), by the recorder (`kitbench record`'s durability, resume, workers and executors, MCAP
logs), into an env in the asked obs mode and control mode. The same control mode replays the executed actions as
they are: PhysX is deterministic in the seed and the actions, so every state, and so every frame, is the source's.
Another control mode tracks the source's joint trajectory: a shadow env in the source's mode replays the executed
actions, and each step the new env is given the action that drives its arm to the joint targets the shadow's
controller set (`policies.joint_targets.joint_target_to_action`); the labels (`action`) are re-expressed the same way.
Where the new mode cannot command a target in one step (a delta mode's box), the arm gets up to
`CATCH_UP_STEPS` more steps to reach it, so a converted episode may be longer than its source.

Every converted episode is checked against its source before it is stored: the same success, and the positions of
the task's objects (every pose field of `observation.environment_state`) within `POSITION_TOLERANCE` of their path
in the source, whatever the timing. An episode that diverges is reported and not stored.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kitbench.config.declare import resolve
from kitbench.envs.interface import as_kitbench
from kitbench.errors import KitbenchError
from kitbench.policies.joint_targets import joint_target_to_action
from kitbench.recording.config import RecordConfig
from kitbench.recording.source import SourceRecording
from kitbench.robots.spec import OPEN

# Largest distance (m) between an object's position in the converted episode and the object's path in the source
# (`path_gap`). The same control mode reproduces the source exactly (0 m), and so do absolute joint targets from
# joint deltas. The end-effector modes reach the same joint targets through their IK a little differently: the
# peg within 0.1-2.5 mm of its source path (LiftPegUpright, seed 0, from joint deltas). 1 cm admits that and
# refuses an episode where the object went elsewhere (15.8-81.3 mm off its path where AssemblingKits conversions
# from absolute joint targets to joint deltas, without catch-up steps, misplaced the shape; 30 episodes).
POSITION_TOLERANCE = 0.01

# Steps a converted episode may add to one source step whose joint target the new mode cannot command at once
# (the measured-delta modes: 0.1 rad or 0.1 m from where the arm is, where the expert's absolute targets lead the
# joints by up to 0.2 rad). From `pd_joint_pos` to pd_joint_delta_pos / pd_ee_delta_pose, expert episodes
# reproduced (one run each): with none, LiftPegUpright 0/30 / 0/30, AssemblingKits 12/30 / 15/30; with 1
# (ManiSkill's replay_trajectory allows 1), 22/30 / 30/30 and 27/30 / 30/30; with 2, 49/50 / 50/50 and
# 45/50 / 50/50 (`bench/convert.py`); 3 and 4 changed nothing.
CATCH_UP_STEPS = 2


class SourceReplay:
    """A policy that replays one source episode a step at a time: each `act` returns what the robot executes and
    sets `label`, the frame's label. In the same control mode they are the source's executed action and label;
    in another, both are re-expressed from the joint targets a shadow env in the source's mode reaches.

    A source step whose joint target lies beyond what one step of the new mode may command (a delta mode's box)
    is given up to `CATCH_UP_STEPS` more steps aimed at the same target before the next source step is taken, as
    ManiSkill's `replay_trajectory` gives one: the converted episode is then longer than its source, and
    `starts` says at which of its frames each source step began."""

    name = "convert"
    phase = None

    def __init__(self, source: SourceRecording, shadow_env):
        self.source = source
        self.shadow = shadow_env  # None: the same control mode
        self.starts: list[int] = []
        self.label: np.ndarray | None = None
        self._t = 0
        self._frame = 0
        self._extra = 0  # steps spent on the current source step beyond its first
        self._targets: tuple[np.ndarray, np.ndarray] | None = None  # (executed, label) joint targets of step t
        self._hand: float | None = None  # the hand's command of the last source step completed

    def reset(self, env, seed: int, obs=None, info=None) -> None:
        self.env = as_kitbench(env)
        self.frames = self.source.episode(seed)
        self.starts = []
        self._t = self._frame = self._extra = 0
        self._hand = None
        self._n_extra = len(self.env.robot_spec.extra_action_names)  # body joints and base, after the hand
        if self.shadow is not None:
            self.shadow.reset(seed=seed)

    def _hold(self) -> np.ndarray:
        return joint_target_to_action(self.env, self.env.controller.joint_target, OPEN)

    def act(self, obs) -> np.ndarray:
        executed, self.label, final = self._next()
        self._frame += 1
        if final:
            self._t += 1
            self._extra = 0
        else:
            self._extra += 1
        return executed

    def _next(self) -> tuple[np.ndarray, np.ndarray, bool]:
        """(executed action, label, whether this env step completes the source step)."""
        t = self._t
        if t >= len(self.frames["executed"]):  # past the source's end: hold still, as a replay does
            hold = self._hold()
            return hold, hold, True
        executed, label = self.frames["executed"][t], self.frames["action"][t]
        if self._extra == 0:
            self.starts.append(self._frame)
        if self.shadow is None:
            return executed, label, True
        s = self.shadow
        n_arm = s.controller.action_space.shape[0] - 1
        if self._extra == 0:  # the source's step, played once in the shadow
            # from the state before the step, in the simulation's units
            label_target = s.controller.preview(s.action_to_sim(label)[:n_arm], s.robot.arm_qpos())
            self.shadow.step(executed)
            self._targets = (s.controller.joint_target.copy(), label_target)
        assert self._targets is not None
        executed_target, label_target = self._targets
        expressed, fits = self._express(executed_target, s.action_to_sim(executed), n_arm)
        labelled = self._express(label_target, s.action_to_sim(label), n_arm)[0]
        final = fits or self._extra >= CATCH_UP_STEPS
        if not final:
            # the arm catches up first; the rest of the step's command (hand, body joints, base) goes with the
            # step that completes it, so that it is applied once, with the arm where the source's was
            self._hold_rest(expressed)
            self._hold_rest(labelled)
        else:
            self._hand = float(expressed[-1 - self._n_extra])
        return expressed, labelled, final

    def _hold_rest(self, action: np.ndarray) -> None:
        """Keep the hand at its last command and stop the body joints and base (zero deltas and velocities)."""
        if self._n_extra:
            action[-self._n_extra :] = 0.0
        if self._hand is not None:
            action[-1 - self._n_extra] = self._hand

    def _express(self, target: np.ndarray, source_action: np.ndarray, n_arm: int) -> tuple[np.ndarray, bool]:
        """The action reaching `target` from the new env's state, and whether it fits the action box (the
        source's body joints and base commands and hand aside, which fit it as they are); `source_action` in the
        simulation's units."""
        action = joint_target_to_action(self.env, target, float(source_action[n_arm]), clip=False)
        # body joints and base: deltas and velocities whatever the arm's mode, in the action's units
        extra = source_action[n_arm + 1 :] * self.env.robot_spec.extra_action_scale()
        if len(extra):
            action[-len(extra) :] = extra
        space = self.env.action_space
        clipped = np.clip(action, space.low, space.high)
        return clipped, bool(np.allclose(clipped, action, atol=1e-6))


def convert_config(source_root: Path, out: Path, **settings):
    """The `RecordConfig` of converting the recording at `source_root` into `out`: the source's task, robot, seeds
    (and whether they hold successes only), reward and settling, with `settings` (obs_mode, control_mode, workers,
    ...; None: the source's or the default) on top."""
    from kitbench.integrity import check_dataset

    if not Path(source_root).is_dir():
        raise KitbenchError(f"{source_root} is not a kitbench recording (no such folder)")
    check_dataset(source_root)
    source = SourceRecording(source_root)
    info = source.info
    if not source.seeds:
        raise KitbenchError(f"{source_root} holds no episode to convert")
    base = {
        "obs_mode": info.obs_mode,
        "control_mode": info.control_mode,
        "robot": info.robot,
        "reward_mode": info.reward_mode,
        "settle_steps": info.settle_steps,
        "repo_id": info.repo_id,
        "rgb_storage": info.rgb_storage,
        "camera_size": info.camera_size,
        "camera_view": info.camera_view,
    }
    fixed = {
        "task": info.task,
        "episodes": len(source.seeds),
        "out": Path(out),
        "seed": min(source.seeds),
        # a source of successes only skips the seeds its expert failed: said so, its seeds' gaps pass the checks
        "only_success": info.only_success,
        "policy": info.policy,
        "policy_options": tuple((info.expert_options or {}).items()),
        "source": Path(source_root),
    }
    return RecordConfig.of(**resolve(("source", base), ("command line", settings), ("conversion", fixed)).values)


def make_replay(source: SourceRecording, control_mode: str) -> SourceReplay:
    """What replays `source` in `control_mode`."""
    from kitbench.registration import make_env

    info = source.info
    shadow = None
    if control_mode != info.control_mode:
        shadow = make_env(info.task, obs_mode="state", control_mode=info.control_mode, robot_uids=info.robot)
    return SourceReplay(source, shadow)


def divergence(source: SourceRecording, episode, pose_columns: list[int], starts: list[int]) -> str | None:
    """Why a converted episode does not reproduce its source (None when it does): success, or objects that left
    their source's path by more than `POSITION_TOLERANCE` (`path_gap`) over the source steps it replayed
    (`starts`: the converted frame at which each source step began)."""
    frames = source.episode(episode.seed)
    if episode.success != frames["success"]:
        return f"success {episode.success} where the source had {frames['success']}"
    replayed = [f for f in starts if f < len(episode.frames)][: len(frames["environment_state"])]
    if not pose_columns or not replayed:
        return None
    converted = np.stack([f["observation.environment_state"] for f in episode.frames[: replayed[-1] + 1]])
    original = frames["environment_state"][: len(replayed)]
    worst = path_gap(converted[:, pose_columns], original[:, pose_columns])
    if worst > POSITION_TOLERANCE:
        limit = POSITION_TOLERANCE * 1000
        return f"an object {worst * 1000:.1f} mm off its path in the source (tolerance {limit:g} mm)"
    return None


def path_gap(converted: np.ndarray, original: np.ndarray) -> float:
    """How far (m) the objects of a converted episode strayed from their path in the source, whatever the timing
    (catch-up steps slow a converted robot down): the Hausdorff distance between the two paths, each the polyline
    through its episode's object positions (frames x [x, y, z] per object, all objects one point). Frame for frame
    equal episodes give 0, and so does the same path taken at another speed."""
    return max(_to_polyline(converted, original), _to_polyline(original, converted))


def _to_polyline(points: np.ndarray, path: np.ndarray) -> float:
    """The largest distance from one of `points` to the polyline through `path` (rows: points)."""
    if len(path) == 1:
        return float(np.linalg.norm(points - path[0], axis=-1).max())
    start, segment = path[:-1], path[1:] - path[:-1]
    length2 = np.maximum((segment**2).sum(axis=-1), 1e-18)
    # each point's nearest point on each segment: its projection, clamped to the segment's ends
    s = np.clip(((points[:, None] - start[None]) * segment[None]).sum(axis=-1) / length2, 0.0, 1.0)
    nearest = start[None] + s[..., None] * segment[None]
    return float(np.linalg.norm(points[:, None] - nearest, axis=-1).min(axis=1).max())


def pose_position_columns(env) -> list[int]:
    """Indices of the x, y, z entries of every pose field in the env's `observation.environment_state`."""
    names = as_kitbench(env).environment_state_names()
    return [i for i, n in enumerate(names) if n.endswith((".x", ".y", ".z")) and n.rsplit(".", 1)[0].endswith("pose")]
