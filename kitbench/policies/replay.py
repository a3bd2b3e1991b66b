"""Replay the actions of a recorded LeRobot dataset episode (from the recorded seed, they reproduce it)."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from kitbench.envs.interface import as_kitbench
from kitbench.errors import KitbenchError
from kitbench.metadata import RecordingInfo, read_columns
from kitbench.policies.joint_targets import joint_target_to_action
from kitbench.policies.registry import policy_source


class ReplayPolicy:
    """`replay:<dataset>[:episode]`: without an episode, each evaluated seed replays the episode recorded with
    that seed; with one, that episode's actions are replayed whatever the seed."""

    phase = None

    def __init__(self, root: str, episode: int | None = None):
        from kitbench.integrity import check_dataset

        self.root = Path(root)
        files = sorted((self.root / "data").rglob("*.parquet"))
        if not files:
            raise KitbenchError(f"no LeRobot dataset at {root} (no data/*/*.parquet)")
        check_dataset(self.root)
        columns = ["episode_index", "frame_index", "action", "episode_seed"]
        frames = read_columns(files, columns).sort_values(["episode_index", "frame_index"])
        self._actions = {
            int(e): np.stack(g["action"].to_numpy()).astype(np.float32) for e, g in frames.groupby("episode_index")
        }
        # lerobot stores a (1,)-shaped feature as a plain column: a scalar per frame
        self._by_seed = {
            int(np.ravel(g["episode_seed"].iloc[0])[0]): int(e) for e, g in frames.groupby("episode_index")
        }
        if episode is not None and episode not in self._actions:
            raise KitbenchError(f"episode {episode} not in {root}; valid choices: 0..{len(self._actions) - 1}")
        self.episode = episode
        self.name = f"replay:{root}" + (f":{episode}" if episode is not None else "")
        self._recording = self._recording_settings()

    def _recording_settings(self) -> RecordingInfo | None:
        """kitbench's settings of the recording (None for a dataset kitbench did not record)."""
        import kitbench

        info = RecordingInfo.read(self.root)
        if info is not None:
            info.require_current(self.root)
        if info is not None and info.kitbench_version != kitbench.__version__:
            warnings.warn(
                f"{self.root} was recorded with kitbench {info.kitbench_version or 'before 0.2.0'}, this is "
                f"{kitbench.__version__}: physics or assets may differ, so replays may not reproduce it",
                stacklevel=3,
            )
        return info

    def requirements(self) -> dict:
        """The recorded actions only mean something in the task and control mode they were recorded in."""
        info = self._recording
        return {} if info is None else {"task": info.task, "control_mode": info.control_mode}

    def reset(self, env, seed, obs, info):
        episode = self.episode if self.episode is not None else self._by_seed.get(seed)
        if episode is None:
            seeds = sorted(self._by_seed)
            hint = (
                f" (evaluate them with --seed {seeds[0]} --episodes {len(seeds)})"
                if seeds == list(range(seeds[0], seeds[0] + len(seeds)))
                else ""
            )
            raise KitbenchError(
                f"{self.root} has no episode recorded with seed {seed}; recorded seeds: {seeds[:10]}"
                f"{'...' if len(seeds) > 10 else ''}{hint}"
            )
        self._env = as_kitbench(env)
        self._queue = list(self._actions[episode])
        if self._queue and self._queue[0].shape != self._env.action_space.shape:
            raise KitbenchError(
                f"recorded actions have shape {self._queue[0].shape}; the env's "
                f"{self._env.control_mode} expects {self._env.action_space.shape}"
            )

    def act(self, obs):
        if self._queue:
            return self._queue.pop(0)
        # past the recorded episode (it ended on success or at the limit): hold still
        return joint_target_to_action(self._env, self._env.controller.joint_target, -1.0)


@policy_source("replay", "replay:<dataset>[:episode]")
def _replay(argument: str | None, device: str, options: dict) -> ReplayPolicy:
    root, _, episode = (argument or "").partition(":")
    return ReplayPolicy(root, int(episode) if episode else None)
