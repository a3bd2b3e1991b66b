"""The expert: each task's own scripted planner (`make_expert()`), usable as a policy in any control mode."""

from __future__ import annotations

from typing import Any

from kitbench.envs.interface import as_kitbench
from kitbench.errors import KitbenchError
from kitbench.policies.joint_targets import joint_target_to_action
from kitbench.policies.registry import policy_source
from kitbench.registration import TASKS


def check_has_expert(env, options: dict[str, Any] | None = None) -> None:
    """Refuse a task that declares no expert, naming those that do, and `options` its expert's config lacks."""
    env = as_kitbench(env)
    if not env.has_expert():
        with_expert = [name for name, entry in TASKS.items() if entry.env_class.has_expert()]
        raise KitbenchError(
            f"task {env.task_id} has no expert planner; tasks with an expert: {', '.join(with_expert) or '(none)'}"
        )
    if options:
        TASKS[env.task_id].env_class.expert_class(env.robot_uid).configured(env.robot_uid, options)


class ExpertPolicy:
    """Runs the task's planner (which plans joint-position targets) and expresses each target in the env's mode.

    `options` replace fields of the planner's config (`--policy-option close_steps=6`): demonstrations shaped for
    a learner, e.g. a longer still grasp that a policy from pixels can see coming."""

    name = "expert"

    def __init__(self, options: dict[str, Any] | None = None):
        self.planner: Any = None  # the task's expert, built at each reset
        self.options = dict(options or {})
        self._env: Any = None

    def reset(self, env, seed, obs, info):
        check_has_expert(env)  # the options are checked where the planner's config is built from them
        self._env = as_kitbench(env)
        self.planner = self._env.make_expert(self.options)
        self.planner.reset(obs, info, seed)

    def act(self, obs):
        target = self.planner.act(obs)
        return joint_target_to_action(self._env, target[:-1], float(target[-1]))

    @property
    def phase(self):
        return self.planner.phase if self.planner is not None else None

    @property
    def tcp_target(self):
        return self.planner.tcp_target if self.planner is not None else None


@policy_source("expert", takes_options=True)
def _expert(argument: str | None, device: str, options: dict) -> ExpertPolicy:
    return ExpertPolicy(options)
