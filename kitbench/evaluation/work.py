"""The evaluation's `Work`: a worker builds the suite's env and the policy once, then scores seeds
(`episode.evaluate_episode`) or films them (`Film`: the episode replayed in an env that renders, returned with its
MP4's bytes, so a video made on another machine reaches the report folder)."""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from kitbench.engine.work import Work
from kitbench.evaluation.episode import EpisodeResult, evaluate_episode
from kitbench.evaluation.suite import Suite


@dataclass(frozen=True)
class Film:
    """Replay `seed` with rendering and encode it at `fps`."""

    seed: int
    fps: int


def make_suite_env(suite: Suite, render: bool = False):
    from kitbench.registration import make_env

    return make_env(
        suite.task,
        obs_mode=suite.obs_mode,
        control_mode=suite.control_mode,
        reward_mode=suite.reward_mode,
        render_mode="rgb_array" if render else None,
    )


class EvalWork(Work):
    def __init__(self, suite: Suite, policy: str):
        self.suite = suite
        self.policy_spec = policy
        self._env: Any = None
        self._video_env: Any = None
        self._policy: Any = None

    def __getstate__(self) -> dict:
        return {"suite": self.suite, "policy": self.policy_spec}  # the settings travel, never a built env

    def __setstate__(self, state: dict) -> None:
        self.__init__(state["suite"], state["policy"])  # type: ignore[misc]

    def setup(self) -> None:
        from kitbench.policies.registry import make_policy

        self._env = make_suite_env(self.suite)
        self._policy = make_policy(self.policy_spec)

    def run(self, job: int | Film) -> EpisodeResult | tuple[EpisodeResult, bytes]:
        """A seed → its score; a `Film` → (the replayed episode's score, the MP4's bytes)."""
        if isinstance(job, Film):
            return self.film(job)
        return evaluate_episode(self._env, self._policy, job)

    def film(self, job: Film) -> tuple[EpisodeResult, bytes]:
        from kitbench.evaluation.video import write_mp4

        if self._video_env is None:  # built on the first video: most evaluations film nothing
            self._video_env = make_suite_env(self.suite, render=True)
        frames: list = []
        result = evaluate_episode(self._video_env, self._policy, job.seed, frames)
        with tempfile.TemporaryDirectory(prefix="kitbench-video-") as scratch:
            path = write_mp4(Path(scratch) / "episode.mp4", frames, job.fps)
            return result, path.read_bytes()

    def close(self) -> None:
        for env in (self._env, self._video_env):
            if env is not None:
                env.close()
        self._env = self._video_env = None
