"""What `kitbench eval` is asked to do: `EvalConfig`, each setting declared once (`kitbench.config`), and how the
command line's settings become one (`eval_config`: a suite file or `--task/--episodes/--seed`, the flags on top)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from kitbench.config import declare
from kitbench.config.checks import non_negative_int, one_of, optional, positive_int, seed
from kitbench.config.declare import setting
from kitbench.engine.config import ExecutorConfig
from kitbench.errors import KitbenchError
from kitbench.evaluation.suite import DEFAULT_FIRST_SEED, Suite, adhoc_suite, load_suite
from kitbench.perturbations import PERTURBATIONS
from kitbench.policies.lerobot_policy import DEVICES, parse_option
from kitbench.registration import canonical_task

COMMAND_LINE = "command line"


@dataclass
class Selection:
    # A suite file (eval/suites/<name>.toml): task, seeds and modes.
    suite_file: Path | None = setting(None, flag="--suite")
    # Episodes (with --suite: its first N seeds).
    episodes: int | None = setting(None, check=optional(positive_int))
    # First seed without a suite, >= 0 (default 1000000; episode k uses seed + k).
    seed: int | None = setting(None, check=optional(seed))


DELAY = "action_delay"  # the perturbation that runs an inference latency


def _delay(name: str, value: object) -> None:
    most = int(PERTURBATIONS[DELAY].maximum)
    if not (isinstance(value, int) and not isinstance(value, bool) and 0 <= value <= most):
        raise KitbenchError(f"{name} must be a whole number of control steps from 0 to {most}, got {value!r}")


@dataclass
class ScoredPolicy:
    # Who is scored: expert, random, zero, replay:<dataset>[:episode] or lerobot:<checkpoint>.
    policy: str = setting("expert")
    # Set a lerobot checkpoint's config field for this run (repeatable), e.g. temporal_ensemble_coeff=0.01,
    # n_action_steps=5, num_inference_steps=10, or the expert's planner's (close_steps=8); the report lists them.
    policy_options: tuple[tuple[str, object], ...] = setting(
        (), flag="--policy-option", repeat=True, parse=parse_option, metavar="KEY=VALUE"
    )
    # Where a lerobot policy's network runs: auto (CUDA when torch sees it), cpu or cuda.
    device: str = setting("auto", check=one_of(DEVICES))
    # Episodes each worker runs in lockstep, one policy call a step for all of them.
    batch_size: int = setting(1, check=positive_int)
    # Inference latency in control steps: each action is executed this many steps after the observation it was
    # computed from (the action_delay perturbation on every episode; the robot holds its first targets meanwhile).
    action_delay: int = setting(0, check=_delay)


@dataclass
class ReportSettings:
    # The report folder (default outputs/eval/<task>/<policy>).
    out: Path | None = setting(None)
    # Replace an existing report in --out (and --save-dataset's dataset).
    overwrite: bool = setting(False)
    # Continue the evaluation a kill, a SIGTERM or a lost cluster stopped in --out, from its journal (the same
    # policy, weights, settings and suite, or it is refused); the report equals an uninterrupted run's.
    resume: bool = setting(False)
    # Episodes to film, failures and successes both.
    videos: int = setting(0, check=non_negative_int)
    # Also store the scored episodes as a LeRobot dataset in DIR (frames, actions, rewards, a dataset card).
    save_dataset: Path | None = setting(None, metavar="DIR")
    # Score the suite's first N seeds only for now: their report is written and the journal kept, so that
    # --resume (with a larger --stop-after, or none) scores on where it stopped.
    stop_after: int | None = setting(None, check=optional(positive_int), metavar="N")


@dataclass
class EvalConfig:
    """`kitbench eval`: the suite, who is scored, where episodes run and where the report goes. `origins`: where
    each of the suite's env settings came from (`COMMAND_LINE` for a flag): a policy's own needs may change the
    suite's settings but not contradict what the command line asked."""

    suite: Suite
    policy: ScoredPolicy = field(default_factory=ScoredPolicy)
    executor: ExecutorConfig = field(default_factory=ExecutorConfig)
    output: ReportSettings = field(default_factory=ReportSettings)
    origins: dict[str, str] = field(default_factory=dict)

    @classmethod
    def of(cls, suite: Suite, policy: str = "expert", out: Path | str | None = None, **settings: Any) -> EvalConfig:
        """A config from a suite and flat settings (`workers=2, videos=1, ...`)."""
        origins = settings.pop("origins", {})
        values = {"policy": policy, "out": None if out is None else Path(out), **settings}
        groups = {"policy": ScoredPolicy, "executor": ExecutorConfig, "output": ReportSettings}
        built = {}
        for name, group in groups.items():
            mine = {k: values.pop(k) for k in list(values) if k in declare.leaves(group)}
            built[name] = declare.build(group, mine)
        if values:
            raise KitbenchError(f"unknown setting(s) {', '.join(values)} for an evaluation")
        return cls(suite, origins=origins, **built)

    def replace(self, **settings: Any) -> EvalConfig:
        return declare.replace(self, **settings)

    @property
    def out(self) -> Path:
        assert self.output.out is not None, "an evaluation has a report folder"
        return self.output.out

    def validate(self) -> None:
        declare.validate(self.policy)
        declare.validate(self.output)
        self.executor.validate()
        delay = self.policy.action_delay
        if delay and any(name == DELAY for name, _ in self.suite.perturbations):
            raise KitbenchError(
                f"--action-delay {delay} and suite {self.suite.name}'s action_delay perturbation set the same latency; "
                "drop one"
            )
        if delay and self.output.save_dataset is not None:
            # a frame's action would be one the robot executed `delay` steps later: not a demonstration
            raise KitbenchError(f"--save-dataset stores each frame's executed action; drop --action-delay {delay}")


ENV_FLAGS = ("obs_mode", "control_mode", "reward_mode", "robot")


def _slug(text: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in text).strip("_.")[-80:] or "policy"


def eval_config(flags: dict[str, Any]) -> EvalConfig:
    """The evaluation the command line's settings describe: a suite file cut to `episodes`, or `episodes` seeds
    from `seed` of `task`; the env flags over the suite's settings, the executor flags over the suite file's."""
    env = {k: flags.get(k) for k in ENV_FLAGS}
    given = {k for k, v in env.items() if v is not None}
    task = flags.get("task")
    if flags.get("suite_file"):
        if flags.get("seed") is not None:
            raise KitbenchError("--seed and --suite exclude each other (a suite fixes its seeds)")
        suite = load_suite(flags["suite_file"])
        if task is not None and canonical_task(task) != suite.task:
            raise KitbenchError(f"--task {task} does not match suite {flags['suite_file']}, which is for {suite.task}")
        if flags.get("episodes") is not None:
            suite = suite.first(flags["episodes"])
        suite = suite.with_modes(**env)
    else:
        missing = [f"--{k}" for k in ("task", "episodes") if flags.get(k) is None]
        if missing:
            raise KitbenchError(f"missing {', '.join(missing)} (or give --suite eval/suites/<name>.toml)")
        first = DEFAULT_FIRST_SEED if flags.get("seed") is None else flags["seed"]
        suite = adhoc_suite(task, flags["episodes"], first, **env)  # type: ignore[arg-type]
    if flags.get("settle_steps") is not None:
        suite = suite.with_modes(settle_steps=flags["settle_steps"])
    executor = suite.executor(**{k: flags.get(k) for k in declare.leaves(ExecutorConfig)})
    policy = flags.get("policy") or "expert"
    out = flags.get("out") or Path("outputs/eval") / suite.task_id / _slug(policy)
    mine = {
        k: v
        for k, v in flags.items()
        if v is not None and k in (*declare.leaves(ScoredPolicy), *declare.leaves(ReportSettings))
    }
    mine.update(policy=policy, out=Path(out))
    config = EvalConfig.of(suite, origins=dict.fromkeys(given, COMMAND_LINE), **mine)
    config.executor = executor
    return config
