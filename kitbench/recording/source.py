"""A kitbench recording as a conversion reads it (`kitbench convert`, `kitbench.recording.convert`)."""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from kitbench.metadata import ACTION_CONVENTION, RecordingInfo, read_columns, read_episodes
from kitbench.robots import ROBOTS


class SourceRecording:
    """What a conversion reads of a kitbench recording: its settings and seeds at once (checks and the recorder's
    seed order need no more), and per seed the frames' executed actions, labels and environment states, and whether
    the episode succeeded, read from the parquet files on the first `episode()` (in the workers that replay it)."""

    def __init__(self, root: Path):
        self.root = Path(root)
        self.info = RecordingInfo.require(self.root)
        self.episodes = read_episodes(self.root)

    @property
    def seeds(self) -> tuple[int, ...]:
        return tuple(int(e.seed) for e in self.episodes)

    def episode(self, seed: int) -> dict:
        return self._frames[seed]

    @functools.cached_property
    def _frames(self) -> dict[int, dict]:
        files = sorted((self.root / "data").rglob("*.parquet"))
        columns = ["episode_index", "frame_index", "action", "executed_action", "observation.environment_state"]
        frames = read_columns(files, columns).sort_values(["episode_index", "frame_index"])
        by_index = {int(e): g for e, g in frames.groupby("episode_index")}
        by_seed = {}
        for episode in self.episodes:
            group = by_index[episode.episode_index]
            by_seed[int(episode.seed)] = {
                "executed": self._migrated(np.stack(group["executed_action"].to_numpy()).astype(np.float32)),
                "action": self._migrated(np.stack(group["action"].to_numpy()).astype(np.float32)),
                "environment_state": np.stack(group["observation.environment_state"].to_numpy()),
                "success": bool(episode.success),
            }
        return by_seed

    def _migrated(self, actions: np.ndarray) -> np.ndarray:
        """Actions in ManiSkill's convention (`ACTION_CONVENTION`). A recording made before it stored them in
        radians, metres and axis-angle vectors (a real arm's units where its robot has them), its gripper with the
        opposite sign (+1 closed; a jaw in percent was already 100 open), its body and base entries unscaled."""
        if self.info.action_convention == ACTION_CONVENTION:
            return actions
        from kitbench.control.controllers import JOINTS, controller_class, make_controller
        from kitbench.control.kinematics import ArmKinematics

        spec, mode = ROBOTS[self.info.robot_uid], self.info.control_mode
        gripper = actions.shape[1] - 1 - len(spec.extra_action_names)
        out = actions.astype(np.float64)
        joints = controller_class(mode).frame == JOINTS
        if not spec.units.expresses(joints):  # then in ManiSkill's form: normalised deltas, Euler rotations
            controller = make_controller(
                mode, np.zeros((len(spec.arm_joints), 2)), functools.partial(ArmKinematics, spec)
            )
            out[:, :gripper] = [controller.encode(row) for row in out[:, :gripper]]
        if not spec.units.gripper_percent:
            out[:, gripper] = -out[:, gripper]
        out[:, gripper + 1 :] *= spec.extra_action_scale()
        return out.astype(actions.dtype)
