"""The evaluation's `Work`: a worker builds the suite's env and the policy once, then scores seeds
(`episode.evaluate_episode`), scores seeds under a perturbation (`Trial`: one env per perturbation and level,
built on its first trial), scores a `Batch` of seeds in lockstep (`episode.evaluate_batch`: one env per episode
of the batch, one policy call a step for all of them), or films them (`Film`: the episode replayed in an env that
renders, returned with its MP4's bytes, so a video made on another machine reaches the report folder)."""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from kitbench.engine.work import Work
from kitbench.evaluation.episode import EpisodeResult, evaluate_batch, evaluate_episode
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


@dataclass(frozen=True)
class Save:
    """Score `seed` and keep the episode's frames for a dataset (`kitbench eval --save-dataset`)."""

    seed: int


@dataclass(frozen=True)
class Batch:
    """Score `seeds` together (under `condition`, a (perturbation, level), when given)."""

    seeds: tuple[int, ...]
    condition: tuple[str, float] | None = None


def suite_env_settings(suite: Suite) -> dict:
    """The settings of `make_env` that a suite decides (the render mode and a perturbation are the caller's)."""
    return {
        "task": suite.task_id,
        "obs_mode": suite.obs_mode,
        "control_mode": suite.control_mode,
        "reward_mode": suite.reward_mode,
        "robot_uids": suite.robot,
        "sensor_configs": suite.sensor_configs,
    }


def make_suite_env(
    suite: Suite, render: bool = False, perturbation: tuple[str, float] | None = None, action_delay: int = 0
):
    """`action_delay`: the policy's inference latency in control steps, the `action_delay` perturbation on every
    episode (a robustness suite's conditions are added to it)."""
    from kitbench.registration import make_env

    settings = suite_env_settings(suite)
    perturbations: dict[str, float] = {"action_delay": action_delay} if action_delay else {}
    perturbations.update([perturbation] if perturbation is not None else [])
    return make_env(
        settings.pop("task"),
        **settings,
        render_mode="rgb_array" if render else None,
        perturbations=perturbations or None,
    )


class EvalWork(Work):
    def __init__(
        self, suite: Suite, policy: str, device: str = "cpu", options: dict | None = None, action_delay: int = 0
    ):
        """`device`: where a trained policy's network runs (resolved: cpu or cuda); `options`: its config's
        settings for this run; `action_delay`: its inference latency in control steps (`make_suite_env`)."""
        self.suite = suite
        self.policy_spec = policy
        self.device = device
        self.options = dict(options or {})
        self.action_delay = action_delay
        self._env: Any = None
        self._video_env: Any = None
        self._perturbed_envs: dict[tuple[str, float], Any] = {}
        self._batch_envs: dict[tuple[str, float] | None, list] = {}
        self._policy: Any = None
        self._batched: Any = None

    def __getstate__(self) -> dict:
        # the settings travel, never a built env
        return {
            "suite": self.suite,
            "policy": self.policy_spec,
            "device": self.device,
            "options": self.options,
            "action_delay": self.action_delay,
        }

    def __setstate__(self, state: dict) -> None:
        self.__init__(  # type: ignore[misc]
            state["suite"], state["policy"], state["device"], state["options"], state["action_delay"]
        )

    def _env_for(self, render: bool = False, perturbation: tuple[str, float] | None = None):
        return make_suite_env(self.suite, render, perturbation, self.action_delay)

    def setup(self) -> None:
        from kitbench.policies.registry import make_policy

        self._env = self._env_for()
        self._policy = make_policy(self.policy_spec, self.device, self.options)

    def run(self, job: int | Trial | Batch | Film) -> EpisodeResult | list[EpisodeResult] | tuple[EpisodeResult, bytes]:
        """A seed → its score; a `Trial` → its score under the perturbation; a `Batch` → its seeds' scores; a
        `Film` → (the replayed episode's score, the MP4's bytes)."""
        if isinstance(job, Film):
            return self.film(job)
        if isinstance(job, Batch):
            return self.run_batch(job)
        if isinstance(job, Save):
            return self.save(job)
        if isinstance(job, Trial):
            condition = (job.perturbation, job.level)
            env = self._perturbed_envs.get(condition)
            if env is None:
                env = self._perturbed_envs[condition] = self._env_for(perturbation=condition)
            return evaluate_episode(env, self._policy, job.seed, settle_steps=self.suite.settle_steps)
        return evaluate_episode(self._env, self._policy, job, settle_steps=self.suite.settle_steps)

    def save(self, job: Save) -> tuple[EpisodeResult, Any]:
        """(the score, the episode's `EpisodeRecord`): played by the recorder's rollout, scored as it goes, so the
        stored episode is the scored one."""
        from kitbench.evaluation.episode import EpisodeScore
        from kitbench.recording.rollout import run_episode

        score = EpisodeScore(self.suite.settle_steps)
        episode = run_episode(self._env, self._policy, job.seed, settle_steps=self.suite.settle_steps, hooks=(score,))
        return score.result(), episode

    def run_batch(self, job: Batch) -> list[EpisodeResult]:
        """The batch's seeds in lockstep, on envs kept per condition (the largest batch's worth)."""
        from kitbench.policies.batch import batched
        from kitbench.policies.registry import make_policy

        envs = self._batch_envs.setdefault(job.condition, [])
        while len(envs) < len(job.seeds):
            envs.append(self._env_for(perturbation=job.condition))
        if self._batched is None:
            self._batched = batched(self._policy, lambda: make_policy(self.policy_spec, self.device, self.options))
        return evaluate_batch(envs, self._batched, list(job.seeds), self.suite.settle_steps)

    def film(self, job: Film) -> tuple[EpisodeResult, bytes]:
        from kitbench.evaluation.video import write_mp4

        if self._video_env is None:  # built on the first video: most evaluations film nothing
            self._video_env = self._env_for(render=True)
        frames: list = []
        result = evaluate_episode(self._video_env, self._policy, job.seed, frames, self.suite.settle_steps)
        with tempfile.TemporaryDirectory(prefix="kitbench-video-") as scratch:
            path = write_mp4(Path(scratch) / "episode.mp4", frames, job.fps)
            return result, path.read_bytes()

    def close(self) -> None:
        batch_envs = [env for envs in self._batch_envs.values() for env in envs]
        for env in (self._env, self._video_env, *self._perturbed_envs.values(), *batch_envs):
            if env is not None:
                env.close()
        self._env = self._video_env = None
        self._perturbed_envs = {}
        self._batch_envs = {}
