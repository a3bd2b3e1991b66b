"""`kitbench convert SRC --out DST`: a recording re-simulated into other observations or another action space.

Each episode of SRC is played again from its seed (`meta/kitbench_episodes.jsonl`) with the actions its robot
executed (`executed_action`), by the recorder (`kitbench record`'s durability, resume, workers and executors, MCAP
logs), into an env in the asked obs mode and control mode. The same control mode replays the executed actions as
they are: PhysX is deterministic in the seed and the actions, so every state, and so every frame, is the source's.
Another control mode tracks the source's joint trajectory: a shadow env in the source's mode replays the executed
actions, and each step the new env is given the action that drives its arm to the joint targets the shadow's
controller set (`policies.convert.joint_target_to_action`); the labels (`action`) are re-expressed the same way.

Every converted episode is checked against its source before it is stored: the poses of the task's objects
(every pose field of `observation.environment_state`) within `POSITION_TOLERANCE` of the source's at every frame
both have, and the same success. An episode that diverges is reported and not stored.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kitbench.errors import KitbenchError
from kitbench.policies.convert import joint_target_to_action
from kitbench.recording.config import RecordConfig
from kitbench.recording.source import SourceRecording

# Largest distance (m) between an object's position in the converted episode and in the source, at any frame. The
# same control mode reproduces the source exactly (0 m), and so do absolute joint targets from joint deltas. The
# end-effector modes reach the same joint targets through their IK a little differently: the peg within 0.1-2.5 mm
# of its source path (LiftPegUpright, seed 0, from joint deltas). 1 cm admits that and refuses an episode where
# the object went elsewhere (11-88 mm where a conversion lost the peg: `bench/convert.py`, README).
POSITION_TOLERANCE = 0.01


class _Tracker:
    """One converted episode's actions, step by step: the source's as they are in the same control mode, else
    re-expressed in the new one by tracking a shadow env in the source's mode. `label()` then `act()` each step."""

    def __init__(self, source: SourceRecording, shadow_env):
        self.source = source
        self.shadow = shadow_env  # None: the same control mode
        self._t = 0
        self._executed: np.ndarray | None = None

    def reset(self, env, seed: int) -> None:
        self.env = env
        self.frames = self.source.episode(seed)
        self._t = 0
        if self.shadow is not None:
            self.shadow.reset(seed=seed)

    def _hold(self) -> np.ndarray:
        u = self.env.unwrapped
        return joint_target_to_action(self.env, u.controller.joint_target, -1.0)

    def label(self) -> np.ndarray:
        """This step's label (`action`); also works out the step's executed action."""
        t = self._t
        if t >= len(self.frames["executed"]):  # past the source's end: hold still, as a replay does
            self._executed = self._hold()
            return self._executed
        executed, label = self.frames["executed"][t], self.frames["action"][t]
        if self.shadow is None:
            self._executed = executed
            return label
        s = self.shadow.unwrapped
        n_arm = s.controller.action_space.shape[0] - 1
        label_target = s.controller.preview(label[:n_arm], s.robot.arm_qpos())  # from the state before the step
        self.shadow.step(executed)
        executed_target = s.controller.joint_target.copy()
        self._executed = self._express(executed_target, executed, n_arm)
        return self._express(label_target, label, n_arm)

    def _express(self, target: np.ndarray, source_action: np.ndarray, n_arm: int) -> np.ndarray:
        action = joint_target_to_action(self.env, target, float(source_action[n_arm]))
        extra = source_action[n_arm + 1 :]  # body joints and base: deltas and velocities whatever the arm's mode
        if len(extra):
            action[-len(extra) :] = extra
        return action

    def act(self) -> np.ndarray:
        assert self._executed is not None
        self._t += 1
        return self._executed


class _Label:
    """The labeler face of a tracker (`rollout.run_episode` asks it first each step)."""

    def __init__(self, tracker: _Tracker):
        self.tracker = tracker

    def reset(self, env, seed, obs, info):
        self.tracker.reset(env, seed)

    def act(self, obs):
        return self.tracker.label()


class _Act:
    """The acting face of a tracker: the step's executed action."""

    name = "convert"
    phase = None

    def __init__(self, tracker: _Tracker):
        self.tracker = tracker

    def reset(self, env, seed, obs, info):
        pass

    def act(self, obs):
        return self.tracker.act()


def convert_config(source_root: Path, out: Path, **settings):
    """The `RecordConfig` of converting the recording at `source_root` into `out`: the source's task, robot, seeds,
    reward and settling, with `settings` (obs_mode, control_mode, workers, ...; None: the source's or the
    default) on top."""
    source = SourceRecording(source_root)
    s = source.settings
    if not source.seeds:
        raise KitbenchError(f"{source_root} holds no episode to convert")
    base = {
        "obs_mode": s["obs_mode"],
        "control_mode": s["control_mode"],
        "robot": s.get("robot"),
        "reward_mode": s.get("reward_mode", "dense"),
        "settle_steps": s.get("settle_steps", 0),
        "repo_id": s.get("repo_id"),
    }
    base.update({k: v for k, v in settings.items() if v is not None})
    return RecordConfig(
        task=s["task"],
        episodes=len(source.seeds),
        out=Path(out),
        seed=min(source.seeds),
        policy=s["policy"],
        source=Path(source_root),
        **base,
    )


def make_replay(source: SourceRecording, control_mode: str):
    """(acting policy, labeler) that replay `source` in `control_mode`."""
    from kitbench.registration import make_env

    settings = source.settings
    shadow = None
    if control_mode != settings["control_mode"]:
        shadow = make_env(
            settings["task"],
            obs_mode="state",
            control_mode=settings["control_mode"],
            robot_uids=settings.get("robot"),
        )
    tracker = _Tracker(source, shadow)
    return _Act(tracker), _Label(tracker)


def divergence(source: SourceRecording, episode, pose_columns: list[int]) -> str | None:
    """Why a converted episode does not reproduce its source (None when it does): success, or an object more than
    `POSITION_TOLERANCE` from where it was."""
    frames = source.episode(episode.seed)
    if episode.success != frames["success"]:
        return f"success {episode.success} where the source had {frames['success']}"
    converted = np.stack([f["observation.environment_state"] for f in episode.frames])
    n = min(len(converted), len(frames["environment_state"]))
    if not pose_columns or n == 0:
        return None
    gap = (converted[:n, pose_columns] - frames["environment_state"][:n, pose_columns]).reshape(n, -1, 3)
    worst = float(np.linalg.norm(gap, axis=-1).max())
    if worst > POSITION_TOLERANCE:
        limit = POSITION_TOLERANCE * 1000
        return f"an object {worst * 1000:.1f} mm from where it was in the source (tolerance {limit:g} mm)"
    return None


def pose_position_columns(env) -> list[int]:
    """Indices of the x, y, z entries of every pose field in the env's `observation.environment_state`."""
    names = env.unwrapped.environment_state_names()
    return [i for i, n in enumerate(names) if n.endswith((".x", ".y", ".z")) and n.rsplit(".", 1)[0].endswith("pose")]
