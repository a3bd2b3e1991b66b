"""The evaluation's `Work`: a worker builds the suite's env and the policy once, then scores seeds
(`episode.evaluate_episode`), scores seeds under a perturbation (`Trial`: one env per perturbation and level,
built on its first trial), or films them (`Film`: the episode replayed in an env that renders, returned with its
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


@dataclass(frozen=True)
class Trial:
    """Score `seed` under `perturbation` at `level` (a robustness suite's condition)."""

    seed: int
    perturbation: str
    level: float


def make_suite_env(suite: Suite, render: bool = False, perturbation: tuple[str, float] | None = None):
    from kitbench.registration import make_env

    return make_env(
        suite.task,
        obs_mode=suite.obs_mode,
        control_mode=suite.control_mode,
        reward_mode=suite.reward_mode,
        render_mode="rgb_array" if render else None,
        robot_uids=suite.robot,
        perturbations=None if perturbation is None else dict([perturbation]),
    )


class EvalWork(Work):
    def __init__(self, suite: Suite, policy: str):
        self.suite = suite
        self.policy_spec = policy
        self._env: Any = None
        self._video_env: Any = None
        self._perturbed_envs: dict[tuple[str, float], Any] = {}
        self._policy: Any = None

    def __getstate__(self) -> dict:
        return {"suite": self.suite, "policy": self.policy_spec}  # the settings travel, never a built env

    def __setstate__(self, state: dict) -> None:
        self.__init__(state["suite"], state["policy"])  # type: ignore[misc]

    def setup(self) -> None:
        from kitbench.policies.registry import make_policy

        self._env = make_suite_env(self.suite)
        self._policy = make_policy(self.policy_spec)

    def run(self, job: int | Trial | Film) -> EpisodeResult | tuple[EpisodeResult, bytes]:
        """A seed → its score; a `Trial` → its score under the perturbation; a `Film` → (the replayed episode's
        score, the MP4's bytes)."""
        if isinstance(job, Film):
            return self.film(job)
        if isinstance(job, Trial):
            condition = (job.perturbation, job.level)
            env = self._perturbed_envs.get(condition)
            if env is None:
                env = self._perturbed_envs[condition] = make_suite_env(self.suite, perturbation=condition)
            return evaluate_episode(env, self._policy, job.seed, settle_steps=self.suite.settle_steps)
        return evaluate_episode(self._env, self._policy, job, settle_steps=self.suite.settle_steps)

    def film(self, job: Film) -> tuple[EpisodeResult, bytes]:
        from kitbench.evaluation.video import write_mp4

        if self._video_env is None:  # built on the first video: most evaluations film nothing
            self._video_env = make_suite_env(self.suite, render=True)
        frames: list = []
        result = evaluate_episode(self._video_env, self._policy, job.seed, frames, self.suite.settle_steps)
        with tempfile.TemporaryDirectory(prefix="kitbench-video-") as scratch:
            path = write_mp4(Path(scratch) / "episode.mp4", frames, job.fps)
            return result, path.read_bytes()

    def close(self) -> None:
        for env in (self._env, self._video_env, *self._perturbed_envs.values()):
            if env is not None:
                env.close()
        self._env = self._video_env = None
        self._perturbed_envs = {}
