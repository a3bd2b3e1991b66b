"""Evaluation suites: a task, a fixed list of seeds, the modes the policy is scored in, how long an episode runs
after its first success, and the perturbations a robustness suite adds.

A suite file (`eval/suites/<name>.toml`) pins everything that decides the numbers, so two evaluations on one
suite are comparable. Suite seeds start far from 0 so that datasets recorded from seed 0 (the recorder's
default) never contain an evaluation episode.

`settle_steps` (default 0): the task ends an episode at its first success; a suite may let it run on for this
many steps, so that what matters is whether the task is still done at the end (a peg let go of must stay
upright). The report gives both of ManiSkill's metrics, `success_once` and `success_at_end`; its headline is
`success_at_end` when `settle_steps` > 0, else `success_once` (with no settling the two are equal).

`purpose` (default `test`): what the seeds are for. Figures are scored on `test` suites; a `validation` suite's
seeds are for choosing (a checkpoint, an execution setting) and must share none with any shipped test suite
(`kitbench select` checks, and refuses a test suite).

`[suite.perturbations]` (a robustness suite): `name = [level, ...]`, each a `kitbench.perturbations` entry. The
suite's seeds run once nominal and once under each perturbation at each level, one at a time.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path

from kitbench.config import declare
from kitbench.config.checks import is_seed, one_of
from kitbench.config.declare import setting
from kitbench.config.files import read_settings
from kitbench.engine.config import ExecutorConfig
from kitbench.env_settings import OBS_MODES, EnvSettings
from kitbench.envs.modes import IMAGE_OBS_MODES
from kitbench.errors import KitbenchError
from kitbench.perturbations import PERTURBATIONS, make_perturbation
from kitbench.registration import TASKS, canonical_task, task_entry
from kitbench.rollout import SettleSettings

OBS_MODES_EVALUABLE = OBS_MODES
SUITE_TABLE = "suite"
DEFAULT_FIRST_SEED = 1_000_000
PURPOSES = ("test", "validation")


@dataclass(eq=True)
class Suite(EnvSettings, SettleSettings):
    """A suite: the env settings (`EnvSettings`), the seeds and everything else that decides the numbers."""

    # The suite's name (default: its file's name).
    name: str = setting("", cli=False)
    # The seeds: a list, or { start = S, count = N }.
    seeds: tuple[int, ...] = setting((), cli=False)
    # What the suite is for.
    description: str = setting("", cli=False)
    # What its seeds are for: test (figures are scored on them) or validation (choosing a checkpoint or a setting).
    purpose: str = setting("test", cli=False, check=one_of(PURPOSES))
    # Robustness perturbations: name = [level, ...] (kitbench.perturbations); each level one run of every seed.
    perturbations: tuple[tuple[str, tuple[float, ...]], ...] = setting((), cli=False)
    # The file it came from.
    source: str | None = field(default=None, compare=False)
    # Where the suite's episodes run by default (its file's executor, workers and ray_address; flags override
    # them). Not part of what the suite is: the numbers do not depend on them.
    runs_on: dict = field(default_factory=dict, compare=False)

    def __post_init__(self):
        super().__post_init__()
        if not isinstance(self.task, str):
            raise KitbenchError(f"{self._where()}unknown task {self.task!r}; valid choices: {', '.join(TASKS)}")
        try:
            declare.validate(self)
            self.check_robot()
            self.check_camera_view()
        except KitbenchError as exc:
            raise KitbenchError(f"{self._where()}{exc}") from None
        self.seeds = tuple(self.seeds)
        self.perturbations = _parse_perturbations(self.perturbations, self._where())
        for name, _levels in self.perturbations:
            if PERTURBATIONS[name].images_only and self.obs_mode not in IMAGE_OBS_MODES:
                raise KitbenchError(
                    f"{self._where()}perturbation {name} changes camera images only; obs_mode {self.obs_mode!r} has "
                    f"none (use rgb or rgbd)"
                )
        if not self.seeds:
            raise KitbenchError(f"{self._where()}no seeds")
        if len(set(self.seeds)) != len(self.seeds):
            raise KitbenchError(f"{self._where()}seeds repeat")
        bad = [s for s in self.seeds if not is_seed(s)]
        if bad:
            raise KitbenchError(f"{self._where()}seeds must be non-negative integers, got {bad[0]!r}")

    __hash__ = None  # type: ignore[assignment]  # mutable settings: compared, never hashed

    @property
    def headline(self) -> str:
        """The metric a report leads with: `success_at_end` when episodes settle after success, else `success_once`."""
        return "success_at_end" if self.settle_steps > 0 else "success_once"

    @property
    def conditions(self) -> list[tuple[str, float] | None]:
        """What each run of the seeds is under: None (nominal) first, then every (perturbation, level)."""
        return [None, *((name, level) for name, levels in self.perturbations for level in levels)]

    def _where(self) -> str:
        return f"suite {self.source}: " if self.source else ""

    def first(self, episodes: int) -> Suite:
        """The suite cut to its first `episodes` seeds."""
        if not isinstance(episodes, int) or episodes < 1:
            raise KitbenchError(f"episodes must be a positive integer, got {episodes!r}")
        if episodes > len(self.seeds):
            raise KitbenchError(f"{self._where()}has {len(self.seeds)} seeds; cannot run {episodes} episodes")
        return replace(self, seeds=self.seeds[:episodes])

    def with_modes(self, **modes) -> Suite:
        """The suite with some modes overridden (None keeps the suite's own)."""
        return replace(self, **{k: v for k, v in modes.items() if v is not None})

    def executor(self, **flags) -> ExecutorConfig:
        """Where to run it: the flags given (None: not given), else the suite file's settings, else the defaults."""
        return declare.build(ExecutorConfig, declare.resolve(("suite", self.runs_on), ("command line", flags)).values)

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "task": self.task,
            "seeds": list(self.seeds),
            "obs_mode": self.obs_mode,
            "control_mode": self.control_mode,
            "reward_mode": self.reward_mode,
            "description": self.description,
            "settle_steps": self.settle_steps,
            "robot": self.robot_uid,
            "camera_size": self.camera_size,
            "camera_view": self.camera_view,
            "perturbations": {name: list(levels) for name, levels in self.perturbations},
            "source": self.source,
        }


def _parse_perturbations(value, where: str) -> tuple[tuple[str, tuple[float, ...]], ...]:
    """`{name: level or [levels]}` (a suite file's table) or (name, levels) pairs, each level checked."""
    pairs = value.items() if isinstance(value, dict) else value
    try:
        pairs = list(pairs)
    except TypeError:
        pairs = None
    if pairs is None or not all(isinstance(p, tuple | list) and len(p) == 2 for p in pairs):
        raise KitbenchError(f"{where}perturbations must be a table of name = [level, ...], got {value!r}")
    out = []
    for name, levels in pairs:
        levels = tuple(levels) if isinstance(levels, list | tuple) else (levels,)
        if not levels:
            raise KitbenchError(f"{where}perturbation {name} has no levels")
        try:
            checked = tuple(make_perturbation(name, level).level for level in levels)
        except KitbenchError as exc:
            raise KitbenchError(f"{where}{exc}") from None
        if len(set(checked)) != len(checked):
            raise KitbenchError(f"{where}perturbation {name} repeats a level: {list(levels)}")
        out.append((name, checked))
    return tuple(out)


def seed_range(start: int, count: int) -> tuple[int, ...]:
    return tuple(range(start, start + count))


def adhoc_suite(task: str, episodes: int, seed: int = DEFAULT_FIRST_SEED, **modes) -> Suite:
    """The suite `--task T --episodes N [--seed S]` means: N consecutive seeds from S."""
    if not isinstance(episodes, int) or episodes < 1:
        raise KitbenchError(f"episodes must be a positive integer, got {episodes!r}")
    if not is_seed(seed):
        raise KitbenchError(f"seed must be a non-negative integer, got {seed!r}")
    task = canonical_task(task)
    return Suite(
        name=f"{task}-seeds-{seed}-{seed + episodes - 1}",
        task=task,
        seeds=seed_range(seed, episodes),
        **{k: v for k, v in modes.items() if v is not None},
    )


def _parse_seeds(value, path: Path) -> tuple[int, ...]:
    if isinstance(value, list):
        return tuple(value)
    if isinstance(value, dict) and set(value) == {"start", "count"}:
        start, count = value["start"], value["count"]
        if is_seed(start) and isinstance(count, int) and not isinstance(count, bool) and count >= 1:
            return seed_range(start, count)
    raise KitbenchError(f"suite {path}: seeds must be a list of integers or {{ start = S, count = N }}, got {value!r}")


SUITE_KEYS = (
    *(name for name in declare.leaves(Suite) if name not in ("source", "runs_on", "pointcloud_points")),
    *declare.leaves(ExecutorConfig),
)


def load_suite(path: str | Path) -> Suite:
    """Read a suite file (keys at top level or under `[suite]`); errors name the file and the key."""
    path = Path(path)
    data = read_settings(path, "suite", SUITE_TABLE, SUITE_KEYS)
    for key in ("task", "seeds"):
        if key not in data:
            raise KitbenchError(f"suite {path}: missing required key {key!r}")
    data["seeds"] = _parse_seeds(data["seeds"], path)
    data.setdefault("name", path.stem)
    runs_on = {k: data.pop(k) for k in list(data) if k in declare.leaves(ExecutorConfig)}
    try:
        declare.validate(declare.build(ExecutorConfig, runs_on))
    except KitbenchError as exc:
        raise KitbenchError(f"suite {path}: {exc}") from None
    return Suite(**data, source=str(path), runs_on=runs_on)


def shipped_suites(task: str, roots: tuple[Path, ...]) -> list[Path]:
    """The suite files under `<root>/eval/suites/` for `task`, the first root that has any (file name order)."""
    task = task_entry(task).name
    for root in roots:
        folder = Path(root) / "eval" / "suites"
        found = []
        for path in sorted(folder.glob("*.toml")):
            try:
                data = tomllib.loads(path.read_text())
            except (OSError, tomllib.TOMLDecodeError):
                continue
            table = data.get(SUITE_TABLE, data)
            named = table.get("task") if isinstance(table, dict) else None
            if isinstance(named, str) and canonical_task(named) == task:
                found.append(path)
        if found:
            return found
    return []
