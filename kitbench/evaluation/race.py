"""`kitbench race`: two policies scored on one suite's seeds in order, a block of seeds at a time, until the
group-sequential paired test (`kitbench.evaluation.sequential`) decides which is better, or the suite runs out.

The two are ordinary `kitbench eval` runs in `<out>/a` and `<out>/b`, each look extending both with `--resume
--stop-after k` (`runner.run_eval`): every scored episode is in their journals, so a killed race resumes (`kitbench
race ... --resume`) into the race an uninterrupted one runs, and a race that stopped early leaves two reports of
the same first k seeds, which `kitbench compare` reads, each with its journal kept, so `kitbench eval --resume`
(without `--stop-after`) scores the rest of the suite. `<out>/race.json` holds the settings, every look and the
decision.
"""

from __future__ import annotations

import json
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from kitbench.config import declare
from kitbench.config.checks import positive_int
from kitbench.config.declare import setting
from kitbench.errors import KitbenchError
from kitbench.evaluation import sequential
from kitbench.evaluation.config import EvalConfig, eval_config
from kitbench.evaluation.provenance import plain, suite_digest
from kitbench.evaluation.significance import check_alpha
from kitbench.policies.lerobot_policy import parse_option
from kitbench.recording.durable import write_durably

RACE_JSON = "race.json"
RACE_VERSION = 2
SIDES = ("a", "b")
TEST = {
    "name": "exact group-sequential McNemar test of the discordant seeds",
    "spending": f"alpha * t^{sequential.SPENDING:g}, t = seeds scored / seeds in the suite",
    "reference": "Lan, DeMets 1983, Biometrika 70(3):659-663; Kim, DeMets 1987, Biometrika 74(1):149-154",
}


def _alpha(name: str, value: object) -> None:
    check_alpha(value)  # type: ignore[arg-type]  # it refuses anything but a number in (0, 1), in one line


@dataclass
class RaceSettings:
    # Policy A: expert, random, zero, replay:<dataset>[:episode] or lerobot:<checkpoint>.
    a: str = setting(required=True, metavar="POLICY")
    # Policy B, as A.
    b: str = setting(required=True, metavar="POLICY")
    # The suite (eval/suites/<name>.toml, or a shipped suite's name): its seeds, in order, are the race's.
    suite_file: Path = setting(required=True, flag="--suite")
    # The race's folder: A's report in OUT/a, B's in OUT/b, the race in OUT/race.json.
    out: Path = setting(required=True)
    # Set one of A's config fields for the race (repeatable), as eval's --policy-option.
    a_options: tuple[tuple[str, object], ...] = setting(
        (), flag="--a-option", repeat=True, parse=parse_option, metavar="KEY=VALUE"
    )
    # Set one of B's config fields for the race (repeatable).
    b_options: tuple[tuple[str, object], ...] = setting(
        (), flag="--b-option", repeat=True, parse=parse_option, metavar="KEY=VALUE"
    )
    # The chance, at most, that the race decides when the policies do not differ, or decides for the worse one.
    alpha: float = setting(0.05, check=_alpha, parse=check_alpha)
    # Seeds both policies score between two looks at the test.
    block: int = setting(10, check=positive_int)
    # Continue the race a kill or a SIGTERM stopped in --out (the same command): both evaluations resume.
    resume: bool = setting(False)
    # Replace a race in --out.
    overwrite: bool = setting(False)


@dataclass
class RaceConfig:
    settings: RaceSettings
    a: EvalConfig
    b: EvalConfig

    @property
    def sides(self) -> dict[str, EvalConfig]:
        return {"a": self.a, "b": self.b}


def race_config(flags: dict[str, Any]) -> RaceConfig:
    """The race the command line describes (`RaceSettings` and eval's execution flags: device, batch size,
    executor, workers), each policy's evaluation built as `kitbench eval` builds it."""
    from kitbench.shipped import find

    mine = {k: v for k, v in flags.items() if k in declare.leaves(RaceSettings)}
    settings: RaceSettings = declare.build(RaceSettings, mine)
    declare.validate(settings)
    if settings.resume and settings.overwrite:
        raise KitbenchError("--resume and --overwrite exclude each other: continue the race, or start it again")
    if (settings.a, dict(settings.a_options)) == (settings.b, dict(settings.b_options)):
        raise KitbenchError(
            f"A and B are the same policy ({settings.a}, options {dict(settings.a_options) or 'none'}): a race "
            "compares two (another policy, checkpoint or --a-option/--b-option)"
        )
    shared = {k: v for k, v in flags.items() if k not in mine}
    configs = {}
    for side in SIDES:
        configs[side] = eval_config(
            {
                **shared,
                "suite_file": find(settings.suite_file, "suite"),
                "policy": getattr(settings, side),
                "policy_options": getattr(settings, f"{side}_options"),
                "out": Path(settings.out) / side,
            }
        )
    suite = configs["a"].suite
    if suite.perturbations:
        raise KitbenchError(
            f"suite {suite.name} is a robustness suite; a race scores nominal seeds in order: use its nominal suite"
        )
    return RaceConfig(settings, configs["a"], configs["b"])


def _race_settings(config: RaceConfig) -> dict:
    """What a resumed race must share with the race it continues (each evaluation checks its own too)."""
    s = config.settings
    return plain(
        {
            "a": {"policy": s.a, "options": dict(s.a_options)},
            "b": {"policy": s.b, "options": dict(s.b_options)},
            "suite": {"name": config.a.suite.name, "digest": suite_digest(config.a.suite)},
            "alpha": s.alpha,
            "block": s.block,
            "test": TEST,
        }
    )


def _check_folder(config: RaceConfig, now: dict) -> None:
    s = config.settings
    out, path = Path(s.out), Path(s.out) / RACE_JSON
    if out.exists() and not out.is_dir():
        raise KitbenchError(f"race folder {out} is a file; --out must be a folder")
    if not s.resume:
        if out.is_dir() and any(out.iterdir()) and not s.overwrite:
            raise KitbenchError(
                f"race folder {out} exists; pass --resume to continue the race in it or --overwrite to replace it"
            )
        return
    if not path.is_file():
        raise KitbenchError(f"race folder {out} holds no race ({RACE_JSON}) to resume; run it without --resume")
    try:
        stored = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise KitbenchError(f"{path} is unreadable ({exc}); pass --overwrite to start the race again") from None
    differences = [
        f"{key}: race {stored.get('settings', {}).get(key)!r}, now {now[key]!r}"
        for key in now
        if stored.get("settings", {}).get(key) != now[key]
    ]
    if differences:
        raise KitbenchError(
            f"cannot resume the race in {out}: " + "; ".join(differences) + " (run it with the race's settings, or "
            "pass --overwrite to start again)"
        )
    if stored.get("finished"):
        raise KitbenchError(
            f"race folder {out} holds a finished race ({stored['decision']} after {stored['episodes']} seeds): "
            "nothing to resume (pass --overwrite to run it again)"
        )


def _write(out: Path, race: dict) -> None:
    write_durably(out / RACE_JSON, (json.dumps(race, indent=1) + "\n").encode())


def _finished_report(config: EvalConfig) -> dict | None:
    """The side's report when its evaluation scored the whole suite (nothing left to resume), else None."""
    from kitbench.evaluation.journal import EvalJournal

    path = config.out / "report.json"
    if EvalJournal(config.out).exists() or not path.is_file():
        return None
    report = json.loads(path.read_text())
    return None if report.get("partial") or report["episodes"] != len(config.suite.seeds) else report


def _outcomes(
    config: EvalConfig, seeds: int, begun: bool, read: bool, progress: bool, engine=None
) -> tuple[list[bool], bool]:
    """The side's headline outcomes on the suite's first `seeds` seeds, and whether its report says them. `read`:
    a resumed race may read them back from the journal (a look replayed); else `kitbench eval --stop-after seeds`
    scores what is missing and writes the report (`begun`: this race has started the side's evaluation)."""
    from kitbench.evaluation.resume import journaled_results
    from kitbench.evaluation.runner import run_eval

    finished = _finished_report(config) if begun else None
    if finished is not None:  # a side that scored the whole suite before the race was stopped
        return [e["success"] for e in finished["per_episode"][:seeds]], seeds == len(config.suite.seeds)
    if read:
        held = journaled_results(config)
        if len(held) >= seeds:
            return [r.success for r in held[:seeds]], False
    report = run_eval(config.replace(stop_after=seeds, resume=begun), progress=progress, engine=engine)
    return [e["success"] for e in report["per_episode"]], True


def run_race(config: RaceConfig, progress: bool = True, say=print) -> dict:
    """Run the race (see the module docstring); returns race.json's content. `say`: where each look's line goes."""
    from kitbench.evaluation.runner import eval_engine, validate

    s = config.settings
    now = _race_settings(config)
    _check_folder(config, now)
    engines = {}
    for name, side in config.sides.items():  # both policies load and fit the suite before anything is written
        if not (s.resume and _finished_report(side) is not None):
            engines[name] = eval_engine(side, validate(side.replace(resume=s.resume, overwrite=s.overwrite)), s.block)
    with ExitStack() as running:  # each side's workers and policy stay up from look to look
        for engine in engines.values():
            running.enter_context(engine)
        return _race(config, now, engines, progress, say)


def _race(config: RaceConfig, now: dict, engines: dict, progress: bool, say) -> dict:
    s = config.settings
    out = Path(s.out)
    sides = config.sides
    if s.overwrite:
        (out / RACE_JSON).unlink(missing_ok=True)
    out.mkdir(parents=True, exist_ok=True)
    total = len(config.a.suite.seeds)
    race: dict[str, Any] = {
        "race_version": RACE_VERSION,
        "settings": now,
        "suite_episodes": total,
        "looks": [],
        "finished": False,
    }
    _write(out, race)
    begun = dict.fromkeys(sides, s.resume)  # a fresh race starts each evaluation (--overwrite: anew) at its first look
    seeds = 0
    history: list[tuple[int, int, int]] = []  # (seeds, only A succeeded, only B) at each look
    while seeds < total:
        seeds = min(seeds + s.block, total)
        outcomes, reported = {}, {}
        for name, side in sides.items():
            if not begun[name]:
                side = side.replace(overwrite=s.overwrite)
            engine = engines.get(name)
            outcomes[name], reported[name] = _outcomes(side, seeds, begun[name], s.resume, progress, engine)
            begun[name] = True
        a, b = outcomes["a"], outcomes["b"]
        a_only = sum(x and not y for x, y in zip(a, b, strict=True))
        b_only = sum(y and not x for x, y in zip(a, b, strict=True))
        history.append((seeds, a_only, b_only))
        assessment = sequential.assess(history, total, s.alpha)
        final = assessment.decided or seeds == total
        for name, side in sides.items():
            if final and not reported[name]:  # a replayed last look: its reports are written now
                _outcomes(side, seeds, True, False, progress, engines.get(name))
        race["looks"].append({**assessment.to_dict(), "a_successes": sum(a), "b_successes": sum(b)})
        say(look_line(race["looks"][-1]))
        if final:
            race.update(_verdict(assessment, sum(a), sum(b)))
        _write(out, race)
        if final:
            break
    return race


def _verdict(assessment: sequential.Assessment, a: int, b: int) -> dict:
    n = assessment.pairs
    return {
        "finished": True,
        "episodes": n,
        "decision": assessment.decision,
        "difference": assessment.difference,
        "interval": list(assessment.interval),
        "success": {"a": {"count": a, "rate": a / n}, "b": {"count": b, "rate": b / n}},
        "reports": {"a": "a/report.json", "b": "b/report.json"},
    }


def look_line(look: dict) -> str:
    return (
        f"look at {look['pairs']} seeds: A {look['a_successes']}/{look['pairs']}, B {look['b_successes']}/"
        f"{look['pairs']}, discordant {look['a_only']} for A, {look['b_only']} for B: "
        + (
            f"decides when one side has {look['needs']} of them"
            if look["needs"] <= look["a_only"] + look["b_only"]
            else "no count of them decides yet"
        )
    )


def _label(side: dict) -> str:
    options = ", ".join(f"{k}={v}" for k, v in side["options"].items())
    return f"{side['policy']} ({options})" if options else side["policy"]


def _percent(x: float) -> str:
    """A signed percentage to 0.1 point, or to two digits where that would round a nonzero end to 0."""
    return f"{x:+.1%}" if x == 0 or abs(x) >= 0.0005 else f"{100 * x:+.2g}%"


def summary_lines(race: dict, out: Path) -> list[str]:
    """What `kitbench race` prints at the end."""
    low, high = race["interval"]
    alpha = race["settings"]["alpha"]
    decision = race["decision"]
    said = decision if decision != sequential.UNDECIDED else f"{decision} at alpha {alpha:g}"
    return [
        f"episodes used: {race['episodes']} of the suite's {race['suite_episodes']} seeds, per policy",
        f"decision: {said} (A {_label(race['settings']['a'])}, B {_label(race['settings']['b'])})",
        (
            f"success: A {race['success']['a']['rate']:.1%}, B {race['success']['b']['rate']:.1%}; A - B "
            f"{race['difference']:+.1%} ({1 - alpha:.0%} interval valid at every look {_percent(low)} to "
            f"{_percent(high)})"
        ),
        f"race: {out / RACE_JSON}; reports: {out / 'a'}, {out / 'b'} (kitbench compare reads them)",
    ]


def main(flags: dict[str, Any]) -> int:
    """`kitbench race`: run the race the flags ask for and print its summary."""
    config = race_config(flags)
    race = run_race(config)
    print("\n".join(summary_lines(race, config.settings.out)))
    return 0
