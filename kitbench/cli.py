"""The `kitbench` command line. Each command's flags are derived from the config its work is declared in
(`kitbench.config`): the same name, type, default, help and check as its recipe or suite key; a command here is
only which config, and what to do with what the command line gave."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import kitbench
from kitbench import faults
from kitbench.config.declare import setting
from kitbench.config.flags import add_flags, given
from kitbench.errors import KitbenchError


def _doctor(flags: dict) -> int:
    from kitbench.doctor import run_doctor

    return run_doctor()


def _demo(flags: dict) -> int:
    from kitbench.config.declare import build
    from kitbench.demo import DemoConfig, run_demo

    run_demo(build(DemoConfig, flags))
    return 0


def _print_summary(config, summary) -> int:
    for line in summary.lines(config.out):
        print(line)
    return summary.exit_code


def _record(flags: dict) -> int:
    from kitbench.recording.recorder import recipe_or_flags, record
    from kitbench.shipped import find

    recipe = flags.pop("recipe", None)
    config = recipe_or_flags(find(recipe, "recipe") if recipe else None, flags)
    return _print_summary(config, record(config))


def _convert(flags: dict) -> int:
    from kitbench.recording.convert import convert_config
    from kitbench.recording.recorder import record

    source, out = flags.pop("source_recording"), flags.pop("out")
    config = convert_config(Path(source), Path(out), **flags)
    return _print_summary(config, record(config))


def _merge(flags: dict) -> int:
    from kitbench.recording.merge import merge

    summary = merge(list(flags["shards"]), flags["out"], flags.get("overwrite", False), flags.get("repo_id"))
    print("\n".join(summary.lines()))
    return 0


def _view(flags: dict) -> int:
    from kitbench.viewer import view

    written = view(flags["dataset"], flags.get("episode", 0), flags.get("save"))
    if written is not None:
        print(f"wrote {written}; open it with: rerun {written}")
    return 0


def _eval(flags: dict) -> int:
    from kitbench.evaluation.config import eval_config
    from kitbench.evaluation.output import summary_lines
    from kitbench.evaluation.runner import run_eval
    from kitbench.shipped import find

    if flags.get("suite_file"):  # a shipped suite by its name, or its checkout path from any folder
        flags["suite_file"] = find(flags["suite_file"], "suite")
    config = eval_config(flags)
    report = run_eval(config)
    print("\n".join(summary_lines(report, config.out)))
    video_error = report["output"].get("video_error")
    if video_error:
        # the scores stand (the report is written), but a run asked for videos it did not get is not a success
        print(f"kitbench eval: videos failed: {video_error}", file=sys.stderr)
        return 1
    return 0


def _compare(flags: dict) -> int:
    from kitbench.evaluation.compare import compare_reports

    comparison = compare_reports(
        flags["a"], flags["b"], flags.get("alpha", "0.05"), flags.get("test", "fisher"),
        flags.get("allow_different_suites", False),
    )  # fmt: skip
    if flags.get("json"):
        comparison.write_json(flags["json"])
    for warning in comparison.warnings:
        print(f"kitbench compare: warning: {warning}", file=sys.stderr)
    print("\n".join(comparison.lines()))
    # a gate for CI: only a significant drop on the headline (success) fails it; the verdict line says why
    return 1 if flags.get("fail_if_worse") and comparison.verdict == "worse" else 0


def _reproduce(flags: dict) -> int:
    from kitbench.config.declare import build
    from kitbench.reproduce import ReproduceConfig, reproduce

    return reproduce(build(ReproduceConfig, flags))


@dataclass
class RecordCommand:
    # A recipe file (datasets/<name>.toml); flags override its values.
    recipe: Path | None = setting(None, positional=True)


@dataclass
class ConvertCommand:
    # A kitbench recording (a LeRobot dataset kitbench recorded).
    source_recording: Path = setting(positional=True, metavar="source")
    # The new dataset's folder.
    out: Path = setting(required=True)


# What a conversion may set; the rest is its source's (task, robot, seeds, reward, settling).
CONVERT_FLAGS = ("obs_mode", "control_mode", "pointcloud_points", "camera_size", "camera_view", "rgb_storage",
                 "workers", "executor", "ray_address", "resume", "overwrite", "mcap", "commit_interval")  # fmt: skip


@dataclass(frozen=True)
class Command:
    help: str
    run: Callable[[dict], int] | str  # or "module:function", imported when the command runs
    settings: tuple[tuple[str, tuple[str, ...] | None], ...] = ()  # (config "module:Class", only these or all)
    skip: tuple[str, ...] = ()


COMMANDS = {
    "doctor": Command("check Python, packages, the Vulkan device and video decoding", _doctor),
    "demo": Command(
        "record a small dataset per task and evaluate the expert and random policies",
        _demo,
        (("kitbench.demo:DemoConfig", None),),
    ),
    "record": Command(
        "record demonstrations into a LeRobot dataset (+ MCAP logs)",
        _record,
        (("kitbench.cli:RecordCommand", None), ("kitbench.recording.config:RecordConfig", None)),
    ),
    "merge": Command(
        "merge recordings of disjoint seed ranges (shards) into one dataset, in seed order",
        _merge,
        (("kitbench.recording.merge:MergeSettings", None),),
    ),
    "convert": Command(
        "re-simulate a recording from its seeds and executed actions into other observations or another action "
        "space (a new LeRobot dataset; episodes that do not reproduce their source are reported, not stored)",
        _convert,
        (("kitbench.cli:ConvertCommand", None), ("kitbench.recording.config:RecordConfig", CONVERT_FLAGS)),
    ),
    "reproduce": Command(
        "record, train and score a shipped config as published (policies/published.toml) and say whether its "
        "figure lands where the published runs predict a new training seed lands (exit 3 when not)",
        _reproduce,
        (("kitbench.reproduce:ReproduceConfig", None),),
    ),
    "view": Command(
        "show a recorded episode in LeRobot's viewer (Rerun), or save it as .rrd",
        _view,
        (("kitbench.viewer:ViewSettings", None),),
    ),
    "eval": Command(
        "score a policy on a fixed seed list; writes report.json/.md, plots and videos",
        _eval,
        (("kitbench.evaluation.config:Selection", None), ("kitbench.evaluation.config:EvalConfig", None)),
        skip=("pointcloud_points",),  # a trained policy's own; no other reads a point cloud
    ),
    "compare": Command(
        "compare two eval reports of one suite: success difference with its 95%% CI and p-value, and a verdict",
        _compare,
        (("kitbench.evaluation.compare:CompareSettings", None),),
    ),
    "select": Command(
        "score each checkpoint of a lerobot-train run on a validation suite: success against step, and the best",
        "kitbench.evaluation.select:run_select",
        (("kitbench.evaluation.select:SelectSettings", None),),
        skip=("seed", "policy", "save_dataset"),
    ),
    "sweep": Command(
        "score a policy over a grid of execution settings (n_action_steps, ensembling, action delay) on one suite",
        "kitbench.evaluation.sweep:run_sweep",
        (("kitbench.evaluation.sweep:SweepSettings", None),),
        skip=("seed", "save_dataset"),
    ),
    "race": Command(
        "score two policies on one suite's seeds in order until a group-sequential paired test decides which is "
        "better (or the suite runs out): the episodes used, the decision and the difference's interval",
        "kitbench.evaluation.race:main",
        (
            ("kitbench.evaluation.race:RaceSettings", None),
            ("kitbench.evaluation.config:ScoredPolicy", ("device", "batch_size")),
            ("kitbench.engine.config:ExecutorConfig", None),
        ),
    ),
}


def _imported(path: str) -> Any:
    import importlib

    module, _, name = path.partition(":")
    return getattr(importlib.import_module(module), name)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="kitbench", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"kitbench {kitbench.__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    for name, command in COMMANDS.items():
        command_parser = sub.add_parser(name, help=command.help)
        for config, only in command.settings:
            add_flags(command_parser, _imported(config), skip=command.skip, only=only)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    command = COMMANDS[args.command]
    flags: dict[str, Any] = {}
    try:
        faults.arm()
        for config, only in command.settings:
            flags.update({k: v for k, v in given(_imported(config), args).items() if only is None or k in only})
        run = _imported(command.run) if isinstance(command.run, str) else command.run
        return run(flags)
    except KitbenchError as exc:
        print(f"kitbench {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
