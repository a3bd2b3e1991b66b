"""The published figures, `policies/published.toml`, read and checked in one place: `kitbench reproduce`,
`bench/learnability.py` and the generated tables (`kitbench.figures`) all read them through `load_published`.

Each row keeps two sets of training seeds apart (docs/results.md, "Method"): `selection_seeds`, the seeds the config
and its recipe were chosen on, and `heldout_seeds`, drawn once and never used to choose anything. `figure_seeds`
says which set the row's figure pools: "selection" until the row is measured on its held-out seeds. A row's
interval is the Wilson 95% interval of its pooled successes, computed, never written.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from kitbench.errors import KitbenchError
from kitbench.shipped import ROOT
from kitbench.training.reference import scaled_minutes

PUBLISHED = ROOT / "policies" / "published.toml"
FIGURE_SEEDS = ("selection", "heldout")
# a figure from held-out seeds pools at least this many (issue's target: a spread between seeds to predict from)
MIN_HELDOUT = 3
REQUIRED = (
    "recipe",
    "demos",
    "steps",
    "selection_seeds",
    "heldout_seeds",
    "figure_seeds",
    "suites",
    "success",
    "episodes",
    "train_minutes",
    "device",
)
# the held-out seeds trained so far, beside a figure from the selection seeds
HELDOUT_FIGURES = ("heldout_success", "heldout_episodes")
# the selection seeds' figures, beside a figure from the held-out seeds
SELECTION_FIGURES = ("selection_suite", "selection_success", "selection_episodes", "selection_on_test_suites")
OPTIONAL = (
    "seed_success",
    "seed_episodes",
    "eval_minutes",
    "eval_batch_size",
    "reference_seconds",
    "train_reference_seconds",
    "step_seconds",
    "threads",
    "cpu",
    *HELDOUT_FIGURES,
    *SELECTION_FIGURES,
)


@dataclass(frozen=True)
class Published:
    """One config's published figure (`policies/published.toml`)."""

    config: str
    recipe: Path
    demos: int
    steps: int
    selection_seeds: tuple[int, ...]  # chose the config and its recipe
    heldout_seeds: tuple[int, ...]  # drawn once, never used to choose anything
    figure_seeds: str  # which of the two sets the figure pools: "selection" or "heldout"
    suites: tuple[str, ...]
    success: int
    episodes: int
    train_minutes: float
    device: str  # the machine the minutes were measured on
    eval_minutes: float | None = None
    eval_batch_size: int = 1
    reference_seconds: float | None = None  # kitbench.training.reference on that machine, on the training's threads
    # the reference read around the training that train_minutes come from, where it is not the scoring's
    train_reference_seconds: float | None = None
    step_seconds: float | None = None  # a step of the published training (kitbench.training.pace, from its log)
    threads: int | None = None  # torch's threads in the published trainings (default: the cores workers leave)
    cpu: bool = False  # a GPU config whose figure's trainings ran on the CPU (`kitbench reproduce --cpu`)
    seed_success: tuple[int, ...] = ()  # each training seed's successes over every suite, and its episodes
    seed_episodes: tuple[int, ...] = ()
    # the held-out seeds trained so far, in `heldout_seeds`' order: each one's successes over every suite, its episodes
    heldout_success: tuple[int, ...] = ()
    heldout_episodes: tuple[int, ...] = ()
    # with a figure from the held-out seeds: each selection seed's figure on the validation suite it was chosen on
    selection_suite: str | None = None
    selection_success: tuple[int, ...] = ()
    selection_episodes: tuple[int, ...] = ()
    # the selection seeds' figures were scored on the figure's own suites, before the split: no validation suite
    selection_on_test_suites: bool = False
    extra: dict = field(default_factory=dict)  # the optional keys as written, for readers that predate their fields

    def __post_init__(self) -> None:
        if not self.seed_success:  # one figure, one run: it stands for itself
            object.__setattr__(self, "seed_success", (self.success,))
            object.__setattr__(self, "seed_episodes", (self.episodes,))

    @property
    def seeds(self) -> tuple[int, ...]:
        """The training seeds the figure pools, in order: `kitbench reproduce` trains the first by default."""
        return self.selection_seeds if self.figure_seeds == "selection" else self.heldout_seeds

    @property
    def rate(self) -> float:
        return self.success / self.episodes

    @property
    def interval(self) -> tuple[float, float]:
        """The pooled figure's Wilson 95% interval."""
        from kitbench.evaluation.stats import wilson_interval

        return wilson_interval(self.success, self.episodes)

    @property
    def seed_rates(self) -> tuple[float, ...]:
        return tuple(s / n for s, n in zip(self.seed_success, self.seed_episodes, strict=True))

    @property
    def selection_rate(self) -> float | None:
        """The selection seeds' pooled figure on the validation suite, where the row keeps it."""
        return sum(self.selection_success) / sum(self.selection_episodes) if self.selection_success else None

    def threads_on(self, cpu: bool) -> int | None:
        """The published trainings' torch threads for a training on the kind of device they ran on (`cpu`: a GPU
        config trained on this CPU); None for another, whose threads theirs do not speak for."""
        return self.threads if cpu == self.cpu else None

    @property
    def training_reference(self) -> float | None:
        """The reference workload's seconds that go with train_minutes (and step_seconds)."""
        return self.train_reference_seconds or self.reference_seconds

    def train_minutes_here(self, here: float, steps: int | None = None, step_here: float | None = None) -> float | None:
        """The published training minutes on this machine for `steps` updates (default: the published run's): scaled
        by a step's seconds here (`step_here`, kitbench.training.pace) where the row keeps its own, else by the
        reference workload's (`here` s); None when the row has neither to scale by."""
        minutes = self.train_minutes * (steps / self.steps if steps else 1.0)
        if step_here and self.step_seconds:
            return scaled_minutes(minutes, self.step_seconds, step_here)
        if not self.training_reference:
            return None
        return scaled_minutes(minutes, self.training_reference, here)

    def eval_minutes_here(self, here: float) -> float | None:
        """One suite's published scoring minutes on a machine whose reference workload took `here` s."""
        if not self.reference_seconds or self.eval_minutes is None:
            return None
        return scaled_minutes(self.eval_minutes, self.reference_seconds, here)


def _seeds(where: str, key: str, value: object) -> tuple[int, ...]:
    if not isinstance(value, list) or not all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in value):
        raise KitbenchError(f"{where}: {key} is {value!r}; give a list of non-negative integers")
    if len(set(value)) != len(value):
        raise KitbenchError(f"{where}: {key} {value} repeats a seed")
    return tuple(value)


def _time(where: str, entry: dict, key: str) -> float | None:
    """A row's minutes or seconds: a positive number, or None where the row leaves it out."""
    if key not in entry:
        return None
    value = entry[key]
    if isinstance(value, bool) or not isinstance(value, int | float) or not value > 0:
        raise KitbenchError(f"{where}: {key} is {value!r}; give a positive number")
    return float(value)


def _flag(where: str, entry: dict, key: str) -> bool:
    value = entry.get(key, False)
    if not isinstance(value, bool):
        raise KitbenchError(f"{where}: {key} is {value!r}; valid choices: true, false")
    return value


def _required_time(where: str, entry: dict, key: str) -> float:
    value = _time(where, entry, key)
    if value is None:
        raise KitbenchError(f"{where} lacks {key}")
    return value


def parse_row(name: str, entry: dict, where: str) -> Published:
    """One row, checked: every required key, no unknown one, the seed sets disjoint, a figure for each seed."""
    where = f"{where}: [{name}]"
    missing = [k for k in REQUIRED if k not in entry]
    if missing:
        raise KitbenchError(f"{where} lacks {', '.join(missing)}")
    unknown = sorted(set(entry) - set(REQUIRED) - set(OPTIONAL))
    if unknown:
        raise KitbenchError(f"{where}: unknown key {unknown[0]!r}; valid keys: {', '.join(REQUIRED + OPTIONAL)}")
    selection = _seeds(where, "selection_seeds", entry["selection_seeds"])
    heldout = _seeds(where, "heldout_seeds", entry["heldout_seeds"])
    shared = sorted(set(selection) & set(heldout))
    if shared:
        raise KitbenchError(
            f"{where}: heldout_seeds share {', '.join(map(str, shared))} with selection_seeds; a held-out seed "
            "is one never used to choose anything"
        )
    if entry["figure_seeds"] not in FIGURE_SEEDS:
        raise KitbenchError(
            f"{where}: figure_seeds is {entry['figure_seeds']!r}; valid choices: {', '.join(FIGURE_SEEDS)}"
        )
    if entry["figure_seeds"] == "heldout" and len(heldout) < MIN_HELDOUT:
        raise KitbenchError(f"{where}: a figure from held-out seeds pools at least {MIN_HELDOUT}; got {list(heldout)}")
    row = Published(
        config=name,
        recipe=ROOT / entry["recipe"],
        demos=int(entry["demos"]),
        steps=int(entry["steps"]),
        selection_seeds=selection,
        heldout_seeds=heldout,
        figure_seeds=entry["figure_seeds"],
        suites=tuple(entry["suites"]),
        success=int(entry["success"]),
        episodes=int(entry["episodes"]),
        train_minutes=_required_time(where, entry, "train_minutes"),
        device=str(entry["device"]),
        eval_minutes=_time(where, entry, "eval_minutes"),
        eval_batch_size=int(entry.get("eval_batch_size", 1)),
        reference_seconds=_time(where, entry, "reference_seconds"),
        train_reference_seconds=_time(where, entry, "train_reference_seconds"),
        step_seconds=_time(where, entry, "step_seconds"),
        threads=None if "threads" not in entry else int(entry["threads"]),
        cpu=_flag(where, entry, "cpu"),
        seed_success=tuple(int(s) for s in entry.get("seed_success", ())),
        seed_episodes=tuple(int(n) for n in entry.get("seed_episodes", ())),
        heldout_success=tuple(int(s) for s in entry.get("heldout_success", ())),
        heldout_episodes=tuple(int(n) for n in entry.get("heldout_episodes", ())),
        selection_suite=entry.get("selection_suite"),
        selection_success=tuple(int(s) for s in entry.get("selection_success", ())),
        selection_episodes=tuple(int(n) for n in entry.get("selection_episodes", ())),
        selection_on_test_suites=entry.get("selection_on_test_suites", False) is True,
        extra={k: entry[k] for k in (*OPTIONAL, "device") if k in entry},
    )
    if not 0 <= row.success <= row.episodes:
        raise KitbenchError(f"{where}: success {row.success} is not within 0..episodes {row.episodes}")
    if len(row.seed_success) != len(row.seeds) or len(row.seed_episodes) != len(row.seeds):
        raise KitbenchError(
            f"{where}: seed_success and seed_episodes give {len(row.seed_success)} and {len(row.seed_episodes)} "
            f"figures for the {len(row.seeds)} {row.figure_seeds} seeds"
        )
    trained = len(row.heldout_success)
    if trained != len(row.heldout_episodes) or trained > len(row.heldout_seeds):
        raise KitbenchError(
            f"{where}: heldout_success and heldout_episodes give {trained} and {len(row.heldout_episodes)} figures; "
            f"give one each for the first held-out seeds trained, of {len(row.heldout_seeds)}"
        )
    if any(not 0 <= s <= n for s, n in zip(row.heldout_success, row.heldout_episodes, strict=True)):
        raise KitbenchError(f"{where}: heldout_success {list(row.heldout_success)} is not within 0..heldout_episodes")
    _check_selection(row, where)
    return row


def _check_selection(row: Published, where: str) -> None:
    """A figure from the held-out seeds keeps its selection seeds' figures beside it (`selection_*`), on a validation
    suite that is none of the figure's; a figure from the selection seeds keeps them as its own."""
    given = [k for k in ("selection_suite", "selection_success", "selection_episodes") if k in row.extra]
    if row.figure_seeds == "selection":
        if given:
            raise KitbenchError(f"{where}: {given[0]} is for a figure from held-out seeds; here seed_success is it")
        return
    if row.heldout_success or row.heldout_episodes:
        raise KitbenchError(f"{where}: heldout_success is seed_success when figure_seeds is heldout; leave it out")
    if row.selection_on_test_suites:  # chosen before the split: the seeds' figures on the test suites themselves
        if "selection_suite" in given:
            raise KitbenchError(f"{where}: selection_on_test_suites has no selection_suite; the figure's are it")
        if len(given) != 2:
            raise KitbenchError(f"{where}: selection_on_test_suites needs selection_success and selection_episodes")
        given.append("selection_suite")
    if len(given) not in (0, 3):
        raise KitbenchError(f"{where}: give selection_suite, selection_success and selection_episodes together")
    if not given:
        return
    if len(row.selection_success) != len(row.selection_seeds) or len(row.selection_episodes) != len(
        row.selection_seeds
    ):
        raise KitbenchError(
            f"{where}: selection_success and selection_episodes give {len(row.selection_success)} and "
            f"{len(row.selection_episodes)} figures for the {len(row.selection_seeds)} selection seeds"
        )
    if any(not 0 <= s <= n for s, n in zip(row.selection_success, row.selection_episodes, strict=True)):
        raise KitbenchError(
            f"{where}: selection_success {list(row.selection_success)} is not within 0..selection_episodes"
        )
    if row.selection_suite is not None and row.selection_suite in row.suites:
        raise KitbenchError(
            f"{where}: selection_suite {row.selection_suite!r} is one of the figure's suites; the seeds that chose "
            "are scored on a validation suite"
        )


def load_published(path: Path = PUBLISHED) -> dict[str, Published]:
    """Every row of `path`, in the file's order; a bad row is one line naming the row and what is wrong."""
    try:
        table = tomllib.loads(Path(path).read_text())
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise KitbenchError(f"published figures {path} unreadable ({exc})") from None
    return {name: parse_row(name, entry, f"published figures {path}") for name, entry in table.items()}
