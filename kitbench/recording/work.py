"""The recording's `Work`: a worker builds the recording env and the policy once, then turns seeds into episodes
(`rollout.run_episode`) with their MCAP logs as bytes, so the episode travels whole to the one writer wherever
the worker runs (a spawned process, a Ray actor on another machine). A policy with a person behind it
(`kitbench.teleop.operated.Operated`) gets its device connected at setup, its hooks on every episode, the same seed
again when the person asks to re-record, and its device let go of at the end."""

from __future__ import annotations

import io
from typing import Any

from kitbench.engine.work import Work
from kitbench.recording.config import RecordConfig, make_recording_env
from kitbench.recording.rollout import EpisodeRecord, run_episode
from kitbench.rollout import Control
from kitbench.teleop.checks import check_record_settings
from kitbench.teleop.operated import OperatorStop, operated


class RecordWork(Work):
    def __init__(self, config: RecordConfig):
        executor, demo = config.executor, config.demo
        check_record_settings(
            config.policy.policy, executor.workers, executor.executor, executor.shard_episodes, demo.action_noise
        )
        self.config = config
        self._env: Any = None
        self._policy: Any = None
        self._labeler: Any = None  # DAgger's second policy, asked at every state

    def __getstate__(self) -> dict:
        return {"config": self.config}  # the settings travel, never a built env

    def __setstate__(self, state: dict) -> None:
        self.__init__(state["config"])  # type: ignore[misc]

    def setup(self) -> None:
        from kitbench.policies.registry import make_policy

        if self.config.source is not None:
            from kitbench.recording.convert import make_replay, pose_position_columns
            from kitbench.recording.source import SourceRecording

            self._env = make_recording_env(self.config)
            self._source = SourceRecording(self.config.source)
            self._policy = make_replay(self._source, self.config.env.control_mode)  # it labels its own frames
            self._poses = pose_position_columns(self._env)
            return
        self._policy = make_policy(self.config.policy.policy, options=dict(self.config.policy.policy_options))
        person = operated(self._policy)
        render = person is not None and person.renders
        step_limit = person is None or person.task_step_limit
        self._env = make_recording_env(self.config, render_mode="rgb_array" if render else None, step_limit=step_limit)
        label = self.config.policy.label
        self._labeler = make_policy(label) if label else None
        if person is not None:
            person.connect()  # before anything is written: a missing device leaves the output as it was

    def run(self, job: int) -> tuple[EpisodeRecord, bytes | None]:
        """Seed → (episode, its MCAP log's bytes or None)."""
        demo = self.config.demo
        person = operated(self._policy)
        while True:
            log = io.BytesIO() if self.config.output.mcap else None  # in memory: a killed worker leaves no file behind
            try:
                episode = run_episode(
                    self._env,
                    self._policy,
                    job,
                    log,
                    action_noise=demo.action_noise,
                    noise_phases=demo.noise_phases,
                    settle_steps=demo.settle_steps,
                    points=self.config.env.pointcloud_points,
                    labeler=self._labeler,
                    hooks=() if person is None else tuple(person.episode_hooks()),
                )
            except OperatorStop:
                return EpisodeRecord(seed=job, task="", control=Control.STOP), None
            if episode.control is not Control.RERECORD:
                break  # a re-recorded episode is dropped whole and its seed run again
        if self.config.source is not None:
            from kitbench.recording.convert import divergence

            episode.rejected = divergence(self._source, episode, self._poses, self._policy.starts)
        return episode, None if log is None else log.getvalue()

    def close(self) -> None:
        person = operated(self._policy)
        if person is not None:
            person.disconnect()
            self._policy = None
        if self._env is not None:
            self._env.close()
            self._env = None
