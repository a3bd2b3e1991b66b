"""The two reports a comparison reads: loading and checking a `report.json`, its counts, how two suites differ,
and the outcomes of the seeds both reports scored, paired seed by seed."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from kitbench.errors import KitbenchError, one_line

# What decides whether two reports measured the same thing (the suite's name, description and file do not).
SUITE_FIELDS = ("task", "seeds", "obs_mode", "control_mode", "reward_mode")
# Fields newer suites have, with the value an older report's suite had without them.
SUITE_DEFAULTS = {"settle_steps": 0, "perturbations": {}, "robot": None}


def _fail(path: Path, what: str) -> KitbenchError:
    return KitbenchError(f"{path} is not a kitbench report: {what}")


def load_report(path: str | Path) -> tuple[Path, dict]:
    """Read a `report.json` (or the report folder holding one) written by `kitbench eval`; returns the file's
    path and the report. Everything the comparison reads is checked here, so a wrong file fails in one line."""
    path = Path(path)
    if path.is_dir():
        path = path / "report.json"
    if not path.is_file():
        raise KitbenchError(f"no report at {path}")
    try:
        report = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise _fail(path, f"cannot read it as JSON ({one_line(exc, typed=False)})") from None
    if not isinstance(report, dict):
        raise _fail(path, "not a JSON object")
    for key in ("report_version", "suite", "success", "criteria", "failure_categories"):
        if key not in report:
            raise _fail(path, f"no {key!r}")
    for key in ("criteria", "failure_categories"):
        if not isinstance(report[key], dict):
            raise _fail(path, f"its {key!r} is not a table")
    suite = report["suite"]
    if not isinstance(suite, dict) or any(k not in suite for k in SUITE_FIELDS):
        raise _fail(path, f"its 'suite' lacks one of {', '.join(SUITE_FIELDS)}")
    if not isinstance(suite["seeds"], list) or not suite["seeds"]:
        raise _fail(path, "its suite has no seeds")
    n = read_count(path, "success", report["success"]).episodes
    for name, entry in report["criteria"].items():
        read_count(path, f"criteria.{name}", entry)
    for name, count in report["failure_categories"].items():
        if not isinstance(count, int) or not 0 <= count <= n:
            raise _fail(path, f"failure_categories.{name} is {count!r}, not a count of at most {n} episodes")
    groups = report.get("report_groups")
    if groups is not None:
        table = report.get(f"per_{groups[1]}") if isinstance(groups, list) and len(groups) == 2 else None
        if not isinstance(table, list) or any(not isinstance(r, dict) or not set(groups) <= set(r) for r in table):
            raise _fail(path, f"its report_groups {groups!r} have no per-group table")
        for row in table:
            read_count(path, f"per_{groups[1]}.{row[groups[0]]}", row)
    episodes = report.get("per_episode")
    if episodes is not None:
        if not isinstance(episodes, list) or len(episodes) != n:
            raise _fail(path, f"per_episode does not hold its {n} episodes")
        for e in episodes:
            if not isinstance(e, dict) or any(k not in e for k in ("seed", "success", "criteria", "failure")):
                raise _fail(path, "a per_episode entry lacks seed, success, criteria or failure")
    return path, report


@dataclass(frozen=True)
class Count:
    """How many of `episodes` episodes had the outcome."""

    count: int
    episodes: int

    @property
    def rate(self) -> float:
        return self.count / self.episodes

    def to_dict(self) -> dict:
        return {"count": self.count, "episodes": self.episodes, "rate": self.rate}


def read_count(path: Path, where: str, entry) -> Count:
    """A report's `rate()` entry ({count, episodes, rate, ci95}) as a Count."""
    if not isinstance(entry, dict) or "episodes" not in entry or ("count" not in entry and "rate" not in entry):
        raise _fail(path, f"{where} has no count and episodes")
    n, k = entry["episodes"], entry.get("count")
    if k is None and isinstance(n, int) and isinstance(entry["rate"], float | int):
        # the count is exact; a hand-made report with only a rate gets the count the rate stands for
        k = round(entry["rate"] * n)
    if not isinstance(n, int) or not isinstance(k, int) or n < 1 or not 0 <= k <= n:
        raise _fail(path, f"{where} counts {k!r} of {n!r} episodes")
    return Count(k, n)


@dataclass(frozen=True)
class Paired:
    """Outcomes on the seeds both reports scored: only A, only B, both, neither had the outcome."""

    a_only: int
    b_only: int
    both: int
    neither: int

    def to_dict(self) -> dict:
        return {"a_only": self.a_only, "b_only": self.b_only, "both": self.both, "neither": self.neither}


def seeds_text(seeds: list) -> str:
    if len(seeds) > 1 and seeds == list(range(seeds[0], seeds[0] + len(seeds))):
        return f"{len(seeds)} seeds {seeds[0]}…{seeds[-1]}"
    shown = ", ".join(map(str, seeds[:4])) + (", …" if len(seeds) > 4 else "")
    return f"{len(seeds)} seed{'s' if len(seeds) != 1 else ''} [{shown}]"


def suite_differences(a: dict, b: dict) -> list[str]:
    """How two reports' suites differ in what decides the numbers, one phrase each, naming both values."""
    sa, sb = a["suite"], b["suite"]
    found = []
    for key in SUITE_FIELDS:
        va, vb = sa[key], sb[key]
        if key == "seeds":
            # the same episodes in another order are the same suite
            if sorted(va) != sorted(vb):
                ta, tb = seeds_text(va), seeds_text(vb)
                if ta == tb:  # same count and ends: name the first seed that is not in both
                    only = sorted(set(va) ^ set(vb))[0]
                    ta, tb = f"{ta} ({'with' if only in va else 'without'} {only})", tb
                found.append(f"seeds: A has {ta}, B has {tb}")
        elif va != vb:
            found.append(f"{key}: A {va!r}, B {vb!r}")
    for key, default in SUITE_DEFAULTS.items():
        va, vb = sa.get(key, default), sb.get(key, default)
        if va != vb:
            found.append(f"{key}: A {va!r}, B {vb!r}")
    return found


def paired_episodes(a: dict, b: dict) -> list[tuple[dict, dict]] | None:
    """A's and B's per-episode results seed by seed, when both reports have them for the same seeds."""
    ea, eb = a.get("per_episode"), b.get("per_episode")
    if ea is None or eb is None:
        return None
    by_seed_a, by_seed_b = {e["seed"]: e for e in ea}, {e["seed"]: e for e in eb}
    if len(by_seed_a) != len(ea) or set(by_seed_a) != set(by_seed_b) or len(by_seed_b) != len(eb):
        return None
    return [(by_seed_a[s], by_seed_b[s]) for s in sorted(by_seed_a)]


def pair(pairs: list[tuple[dict, dict]], outcome) -> Paired:
    counts = {(True, True): 0, (True, False): 0, (False, True): 0, (False, False): 0}
    for ea, eb in pairs:
        counts[(bool(outcome(ea)), bool(outcome(eb)))] += 1
    return Paired(
        a_only=counts[(True, False)],
        b_only=counts[(False, True)],
        both=counts[(True, True)],
        neither=counts[(False, False)],
    )
