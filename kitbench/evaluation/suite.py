"""Evaluation suites: a task, a fixed list of seeds, the modes the policy is scored in, how long an episode runs
after its first success, and the perturbations a robustness suite adds.

A suite file (`eval/suites/<name>.toml`) pins everything that decides the numbers, so two evaluations on one
suite are comparable. Suite seeds start far from 0 so that datasets recorded from seed 0 (the recorder's
default) never contain an evaluation episode.

`settle_steps` (default 0): the task ends an episode at its first success; a suite may let it run on for this
many steps, so that what matters is whether the task is still done at the end (a peg let go of must stay
upright). The report gives both of ManiSkill's metrics, `success_once` and `success_at_end`; its headline is
`success_at_end` when `settle_steps` > 0, else `success_once` (with no settling the two are equal).

`[suite.perturbations]` (a robustness suite): `name = [level, ...]`, each a `kitbench.perturbations` entry. The
suite's seeds run once nominal and once under each perturbation at each level, one at a time.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path

from kitbench.control.controllers import CONTROL_MODES
from kitbench.envs.modes import IMAGE_OBS_MODES, REWARD_MODES
from kitbench.errors import KitbenchError
from kitbench.perturbations import PERTURBATIONS, make_perturbation
from kitbench.registration import TASKS, canonical_task, task_entry
from kitbench.settings import check_seed, is_seed, read_settings

OBS_MODES_EVALUABLE = ("state", *IMAGE_OBS_MODES)
SUITE_KEYS = (
    "name",
    "task",
    "seeds",
    "obs_mode",
    "control_mode",
    "reward_mode",
    "description",
    "executor",
    "workers",
    "ray_address",
    "settle_steps",
    "perturbations",
    "robot",
)
SUITE_TABLE = "suite"
DEFAULT_FIRST_SEED = 1_000_000


@dataclass(frozen=True)
class Suite:
    name: str
    task: str
    seeds: tuple[int, ...]
    obs_mode: str = "state"
    control_mode: str = "pd_joint_delta_pos"
    reward_mode: str = "dense"
    description: str = ""
    settle_steps: int = 0  # steps an episode runs on after its first success
    robot: str | None = None  # the robot (`robot_uids`); None: the task's default
    # (name, levels) pairs; each level is one run of every seed under that perturbation
    perturbations: tuple[tuple[str, tuple[float, ...]], ...] = ()
    source: str | None = field(default=None, compare=False)  # the file it came from
    # Where the suite's episodes run by default (kitbench.engine.ExecutorConfig; flags override them). Not part of
    # what the suite is: the numbers do not depend on them, so they are left out of comparisons and reports.
    executor: str | None = field(default=None, compare=False)
    workers: int | None = field(default=None, compare=False)
    ray_address: str | None = field(default=None, compare=False)

    def __post_init__(self):
        # stored by its short name, so reports and output folders are the same whichever spelling was given
        object.__setattr__(self, "task", canonical_task(self.task))
        if not isinstance(self.task, str) or self.task not in TASKS:
            raise KitbenchError(f"{self._where()}unknown task {self.task!r}; valid choices: {', '.join(TASKS)}")
        for key, value, valid in (
            ("obs_mode", self.obs_mode, OBS_MODES_EVALUABLE),
            ("control_mode", self.control_mode, CONTROL_MODES),
            ("reward_mode", self.reward_mode, REWARD_MODES),
        ):
            if value not in valid:
                raise KitbenchError(f"{self._where()}unknown {key} {value!r}; valid choices: {', '.join(valid)}")
        if self.robot is not None:
            supported = task_entry(self.task).env_class.supported_robots
            if self.robot not in supported:
                raise KitbenchError(
                    f"{self._where()}robot {self.robot!r} is not supported by {self.task}; valid choices: "
                    f"{', '.join(supported)}"
                )
        if isinstance(self.settle_steps, bool) or not isinstance(self.settle_steps, int) or self.settle_steps < 0:
            raise KitbenchError(f"{self._where()}settle_steps must be an integer >= 0, got {self.settle_steps!r}")
        object.__setattr__(self, "perturbations", _parse_perturbations(self.perturbations, self._where()))
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

    @property
    def robot_uid(self) -> str:
        """The robot the suite runs: its own, else the task's default."""
        return self.robot or task_entry(self.task).env_class.supported_robots[0]

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
    check_seed(seed)
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


def load_suite(path: str | Path) -> Suite:
    """Read a suite file (keys at top level or under `[suite]`); errors name the file and the key."""
    path = Path(path)
    data = read_settings(path, "suite", SUITE_TABLE, SUITE_KEYS)
    for key in ("task", "seeds"):
        if key not in data:
            raise KitbenchError(f"suite {path}: missing required key {key!r}")
    data["seeds"] = _parse_seeds(data["seeds"], path)
    data.setdefault("name", path.stem)
    return Suite(**data, source=str(path))


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
