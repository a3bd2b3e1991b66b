"""The `kitbench` command line."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import kitbench
from kitbench.engine.config import EXECUTORS
from kitbench.envs.modes import REWARD_MODES
from kitbench.errors import KitbenchError
from kitbench.registration import GYM_NAMESPACE, TASKS, canonical_task


def _doctor(args) -> int:
    from kitbench.doctor import run_doctor

    return run_doctor()


def _demo(args) -> int:
    from kitbench.demo import DemoConfig, run_demo

    config = DemoConfig(
        out=Path(args.out),
        episodes=args.episodes,
        eval_episodes=args.eval_episodes,
        workers=args.workers,
        tasks=tuple(canonical_task(t) for t in args.task) if args.task else DemoConfig.tasks,
    )
    try:
        run_demo(config)
    except KitbenchError as exc:
        print(f"kitbench demo: error: {exc}", file=sys.stderr)
        return 2
    return 0


def _record(args) -> int:
    from kitbench.recording.recorder import RecordConfig, load_recipe

    flags = {
        "task": args.task,
        "episodes": args.episodes,
        "out": args.out,
        "seed": args.seed,
        "label": args.label,
        "policy": args.policy,
        "only_success": args.only_success or None,
        "repo_id": args.repo_id,
        "max_attempts": args.max_attempts,
        "action_noise": args.action_noise,
        "noise_phases": None if args.noise_phases is None else tuple(args.noise_phases.split(",")),
        "settle_steps": args.settle_steps,
        "reward_mode": args.reward_mode,
        "shard_episodes": args.shard_episodes,
        "robot": args.robot,
        **_recording_flags(args),
    }

    def config():
        if args.recipe:
            return load_recipe(Path(args.recipe), **flags)
        missing = [f"--{k}" for k in ("task", "episodes", "out") if flags[k] is None]
        if missing:
            raise KitbenchError(f"missing {', '.join(missing)} (or give a recipe file)")
        return RecordConfig(**{k: v for k, v in flags.items() if v is not None} | {"out": Path(args.out)})

    return _run_recording("record", config)


def _recording_flags(args) -> dict:
    """The flags `kitbench record` and `kitbench convert` share: what is stored and how the recording runs
    (None: the recipe's, the source's or the default)."""
    return {
        "obs_mode": args.obs_mode,
        "control_mode": args.control_mode,
        "pointcloud_points": args.pointcloud_points,
        "rgb_storage": args.rgb_storage,
        "workers": args.workers,
        "executor": args.executor,
        "ray_address": args.ray_address,
        "resume": args.resume or None,
        "overwrite": args.overwrite or None,
        "mcap": args.mcap,
        "commit_interval": args.commit_interval,
    }


def _run_recording(command: str, config) -> int:
    """Build the `RecordConfig` (`config()`) and record it: a bad setting is one line and exit status 2, else
    the summary and the recorder's exit status."""
    from kitbench.recording.recorder import record

    try:
        recording = config()
        summary = record(recording)
    except KitbenchError as exc:
        print(f"kitbench {command}: error: {exc}", file=sys.stderr)
        return 2
    for line in summary.lines(recording.out):
        print(line)
    return summary.exit_code


def _merge(args) -> int:
    from kitbench.recording.merge import merge

    try:
        summary = merge([Path(s) for s in args.shards], Path(args.out), overwrite=args.overwrite, repo_id=args.repo_id)
    except KitbenchError as exc:
        print(f"kitbench merge: error: {exc}", file=sys.stderr)
        return 2
    for line in summary.lines():
        print(line)
    return 0


def _view(args) -> int:
    from kitbench.viewer import view

    try:
        written = view(Path(args.dataset), args.episode, Path(args.save) if args.save else None)
    except KitbenchError as exc:
        print(f"kitbench view: error: {exc}", file=sys.stderr)
        return 2
    if written is not None:
        print(f"wrote {written}; open it with: rerun {written}")
    return 0


def _convert(args) -> int:
    from kitbench.recording.convert import convert_config

    return _run_recording(
        "convert", lambda: convert_config(Path(args.source), Path(args.out), **_recording_flags(args))
    )


def _slug(text: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in text).strip("_.")[-80:] or "policy"


def eval_config_from_args(args):
    """The evaluation the flags describe: a suite file cut to --episodes, or --episodes seeds from --seed."""
    from kitbench.evaluation.runner import EvalConfig
    from kitbench.evaluation.suite import DEFAULT_FIRST_SEED, adhoc_suite, load_suite
    from kitbench.policies.lerobot_policy import parse_option

    modes = {
        "obs_mode": args.obs_mode,
        "control_mode": args.control_mode,
        "reward_mode": args.reward_mode,
        "robot": args.robot,
    }
    explicit = frozenset(k for k, v in modes.items() if v is not None)
    if args.suite:
        if args.seed is not None:
            raise KitbenchError("--seed and --suite exclude each other (a suite fixes its seeds)")
        suite = load_suite(args.suite)
        if args.task is not None and canonical_task(args.task) != suite.task:
            raise KitbenchError(f"--task {args.task} does not match suite {args.suite}, which is for {suite.task}")
        if args.episodes is not None:
            suite = suite.first(args.episodes)
        suite = suite.with_modes(**modes)
    else:
        missing = [f"--{k}" for k in ("task", "episodes") if getattr(args, k) is None]
        if missing:
            raise KitbenchError(f"missing {', '.join(missing)} (or give --suite eval/suites/<name>.toml)")
        suite = adhoc_suite(args.task, args.episodes, DEFAULT_FIRST_SEED if args.seed is None else args.seed, **modes)
    if args.settle_steps is not None:
        suite = dataclasses.replace(suite, settle_steps=args.settle_steps)
    out = Path(args.out) if args.out else Path("outputs/eval") / suite.task / _slug(args.policy)

    def chosen(flag, key, default):  # the flag, else the suite's setting, else the default
        return flag if flag is not None else default if getattr(suite, key) is None else getattr(suite, key)

    return EvalConfig(
        suite=suite,
        policy=args.policy,
        out=out,
        workers=chosen(args.workers, "workers", 1),
        executor=chosen(args.executor, "executor", "local"),
        ray_address=chosen(args.ray_address, "ray_address", "auto"),
        videos=args.videos,
        explicit=explicit,
        overwrite=args.overwrite,
        batch_size=args.batch_size,
        device=args.device,
        policy_options=tuple(parse_option(o) for o in args.policy_option or ()),
        save_dataset=Path(args.save_dataset) if args.save_dataset else None,
    )


def _eval(args) -> int:
    from kitbench.evaluation.runner import run_eval, summary_lines

    try:
        config = eval_config_from_args(args)
        report = run_eval(config)
    except KitbenchError as exc:
        print(f"kitbench eval: error: {exc}", file=sys.stderr)
        return 2
    for line in summary_lines(report, config.out):
        print(line)
    video_error = report["output"].get("video_error")
    if video_error:
        # the scores stand (the report is written), but a run asked for videos it did not get is not a success
        print(f"kitbench eval: videos failed: {video_error}", file=sys.stderr)
        return 1
    return 0


def _reproduce(args) -> int:
    from kitbench.reproduce import PUBLISHED, ReproduceConfig, reproduce

    config = ReproduceConfig(
        config=args.config.removesuffix(".json").rsplit("/", 1)[-1],
        out=Path(args.out or f"outputs/reproduce/{args.config}"),
        steps=args.steps,
        demos=args.demos,
        eval_episodes=args.eval_episodes,
        seed=args.seed,
        workers=args.workers,
        published=Path(args.published) if args.published else PUBLISHED,
    )
    try:
        return reproduce(config)
    except KitbenchError as exc:
        print(f"kitbench reproduce: error: {exc}", file=sys.stderr)
        return 2


def _compare(args) -> int:
    from kitbench.evaluation.compare import compare_reports

    try:
        comparison = compare_reports(
            args.a,
            args.b,
            alpha=args.alpha,
            test=args.test,
            allow_different_suites=args.allow_different_suites,
        )
        if args.json:
            comparison.write_json(args.json)
    except KitbenchError as exc:
        print(f"kitbench compare: error: {exc}", file=sys.stderr)
        return 2
    for warning in comparison.warnings:
        print(f"kitbench compare: warning: {warning}", file=sys.stderr)
    for line in comparison.lines():
        print(line)
    # a gate for CI: only a significant drop on the headline (success) fails it; the verdict line says why
    return 1 if args.fail_if_worse and comparison.verdict == "worse" else 0


def _executor_flags(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--executor",
        help=f"where episodes run: {' or '.join(EXECUTORS)} (default local: this process, or --workers processes)",
    )
    parser.add_argument(
        "--ray-address",
        dest="ray_address",
        help="with --executor ray: auto (default: the running cluster, else a local one), local, or a head's host:port",
    )


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="kitbench", description=__doc__)
    parser.add_argument("--version", action="version", version=f"kitbench {kitbench.__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    doctor = sub.add_parser("doctor", help="check Python, packages, the Vulkan device and video decoding")
    doctor.set_defaults(func=_doctor)
    demo = sub.add_parser("demo", help="record a small dataset per task and evaluate the expert and random policies")
    demo.add_argument("--out", default="outputs/demo", help="output folder (default: outputs/demo)")
    demo.add_argument("--episodes", type=int, default=5, help="expert episodes recorded per task (default 5)")
    demo.add_argument(
        "--eval-episodes",
        dest="eval_episodes",
        type=int,
        default=10,
        help="episodes per policy evaluation (default 10, the short suites)",
    )
    demo.add_argument("--workers", type=int, default=1, help="simulator processes (default 1)")
    demo.add_argument("--task", action="append", help="only this task (repeatable; default both)")
    demo.set_defaults(func=_demo)
    rec = sub.add_parser("record", help="record demonstrations into a LeRobot dataset (+ MCAP logs)")
    rec.add_argument("recipe", nargs="?", help="a recipe file (datasets/<name>.toml); flags override its values")
    rec.add_argument("--task", help=f"one of {', '.join(TASKS)} (or its gym id {GYM_NAMESPACE}/<task>)")
    rec.add_argument("--episodes", type=int, help="episodes to store")
    rec.add_argument("--out", help="dataset folder (the LeRobot root; MCAP logs go to <out>/mcap)")
    rec.add_argument("--seed", type=int, help="first seed, >= 0 (default 0); episode k uses seed + k")
    rec.add_argument(
        "--obs-mode",
        dest="obs_mode",
        help="state (default); rgb, rgbd, depth, segmentation or '+'-joined textures (rgb+depth+segmentation); "
        "pointcloud",
    )
    rec.add_argument(
        "--pointcloud-points",
        dest="pointcloud_points",
        type=int,
        help="points stored per frame with --obs-mode pointcloud (default 1024), sampled with the episode's seed",
    )
    rec.add_argument(
        "--rgb-storage",
        dest="rgb_storage",
        help="how rgb frames are stored: video (default; h264, lossy) or images (PNG, lossless, ~5x the bytes)",
    )
    rec.add_argument("--control-mode", dest="control_mode", help="action space recorded (default pd_joint_delta_pos)")
    rec.add_argument(
        "--robot", help="one of the task's robots (default: its first, e.g. panda; or fetch); stored with the recording"
    )
    rec.add_argument(
        "--policy",
        help="expert (default), random, zero, replay:<dataset>[:episode] or lerobot:<checkpoint> (its rollouts; "
        "with --only-success its successes)",
    )
    rec.add_argument(
        "--label",
        help="expert: store as each frame's action what the task's expert commands from the state the policy reached "
        "(DAgger); executed_action keeps the policy's own",
    )
    rec.add_argument("--only-success", dest="only_success", action="store_true", help="store successful episodes only")
    rec.add_argument(
        "--workers",
        type=int,
        help="simulator workers (processes or Ray actors; default 1); the dataset does not depend on it",
    )
    _executor_flags(rec)
    rec.add_argument("--resume", action="store_true", help="continue an interrupted recording in --out")
    rec.add_argument("--overwrite", action="store_true", help="replace an existing --out")
    rec.add_argument("--mcap", action=argparse.BooleanOptionalAction, default=None, help="write MCAP logs (default on)")
    rec.add_argument(
        "--repo-id", dest="repo_id", help="dataset repo id, [namespace/]name as on the Hub (default kitbench/<task>)"
    )
    rec.add_argument(
        "--commit-interval",
        dest="commit_interval",
        type=float,
        help="seconds between commits (default 30; 0 commits after every episode)",
    )
    rec.add_argument(
        "--max-attempts",
        dest="max_attempts",
        type=int,
        help="episodes to attempt, stored or not, before giving up with exit status 3 (default 10 x --episodes)",
    )
    rec.add_argument(
        "--action-noise",
        dest="action_noise",
        type=float,
        help="execute actions with seeded Gaussian noise, in units of the control mode's noise unit (0.02 rad a "
        "joint); the dataset keeps the clean actions as labels (default 0: none)",
    )
    rec.add_argument(
        "--noise-phases",
        dest="noise_phases",
        help="comma-separated expert phases the action noise runs in, e.g. transport,align (default: all phases)",
    )
    rec.add_argument(
        "--settle-steps",
        dest="settle_steps",
        type=int,
        help="steps recorded after an episode's first success, the policy finishing the task (default 0)",
    )
    rec.add_argument(
        "--reward-mode",
        dest="reward_mode",
        help=f"reward stored in next.reward: {', '.join(REWARD_MODES)} (default dense)",
    )
    rec.add_argument(
        "--shard-episodes",
        dest="shard_episodes",
        type=int,
        help="episodes per shard: each worker writes whole shards, merged at the end, so writing scales with the "
        "workers (default 0: one writer; see docs/scale-out.md)",
    )
    rec.set_defaults(func=_record)
    mrg = sub.add_parser(
        "merge", help="merge recordings of disjoint seed ranges (shards) into one dataset, in seed order"
    )
    mrg.add_argument("shards", nargs="+", help="dataset folders of finished recordings with the same settings")
    mrg.add_argument("--out", required=True, help="the merged dataset's folder (new, or replaced with --overwrite)")
    mrg.add_argument("--overwrite", action="store_true", help="replace an existing --out")
    mrg.add_argument("--repo-id", dest="repo_id", help="repo id of the merged dataset (default: the shards')")
    mrg.set_defaults(func=_merge)
    cv = sub.add_parser(
        "convert",
        help="re-simulate a recording from its seeds and executed actions into other observations or another "
        "action space (a new LeRobot dataset; episodes that do not reproduce their source are reported, not stored)",
    )
    cv.add_argument("source", help="a kitbench recording (a LeRobot dataset kitbench recorded)")
    cv.add_argument("--out", required=True, help="the new dataset's folder")
    cv.add_argument("--obs-mode", dest="obs_mode", help="observations to store (default: the source's)")
    cv.add_argument(
        "--control-mode",
        dest="control_mode",
        help="action space to store (default: the source's); another one tracks the source's joint trajectory",
    )
    cv.add_argument("--pointcloud-points", dest="pointcloud_points", type=int, help="as kitbench record's")
    cv.add_argument("--rgb-storage", dest="rgb_storage", help="as kitbench record's (default: the source's)")
    cv.add_argument("--workers", type=int, help="simulator workers (default 1); the dataset does not depend on it")
    _executor_flags(cv)
    cv.add_argument("--resume", action="store_true", help="continue an interrupted conversion in --out")
    cv.add_argument("--overwrite", action="store_true", help="replace an existing --out")
    cv.add_argument("--mcap", action=argparse.BooleanOptionalAction, default=None, help="write MCAP logs (default on)")
    cv.add_argument("--commit-interval", dest="commit_interval", type=float, help="as kitbench record's (default 30)")
    cv.set_defaults(func=_convert)
    rp = sub.add_parser(
        "reproduce",
        help="record, train and score a shipped config as published (policies/published.toml) and say whether its "
        "figure falls inside the published interval (exit 3 when not)",
    )
    rp.add_argument("config", help="a config in policies/ with a published figure, e.g. act_lift_peg_upright_state")
    rp.add_argument("--out", help="working folder (default outputs/reproduce/<config>; a recording there is resumed)")
    rp.add_argument("--steps", type=int, help="training steps (default: the published run's)")
    rp.add_argument("--demos", type=int, help="demonstrations (default: the published run's)")
    rp.add_argument("--eval-episodes", dest="eval_episodes", type=int, help="each suite's first N seeds (default all)")
    rp.add_argument("--seed", type=int, help="lerobot-train --seed (default: the published run's first)")
    rp.add_argument("--workers", type=int, default=1, help="recording and evaluation processes (default 1)")
    rp.add_argument("--published", help="a published-figures file (default policies/published.toml)")
    rp.set_defaults(func=_reproduce)
    vw = sub.add_parser("view", help="show a recorded episode in LeRobot's viewer (Rerun), or save it as .rrd")
    vw.add_argument("dataset", help="a dataset folder (LeRobot v3)")
    vw.add_argument("--episode", type=int, default=0, help="episode index (default 0)")
    vw.add_argument(
        "--save",
        help="write a .rrd file into this folder instead of opening a viewer (default without a display: outputs/view)",
    )
    vw.set_defaults(func=_view)
    ev = sub.add_parser("eval", help="score a policy on a fixed seed list; writes report.json/.md, plots and videos")
    ev.add_argument(
        "--task", help=f"one of {', '.join(TASKS)} (or its gym id {GYM_NAMESPACE}/<task>; implied by --suite)"
    )
    ev.add_argument(
        "--policy",
        default="expert",
        help="expert (default), random, zero, replay:<dataset>[:episode] or lerobot:<checkpoint>",
    )
    ev.add_argument("--episodes", type=int, help="episodes (with --suite: its first N seeds)")
    ev.add_argument(
        "--seed", type=int, help="first seed without a suite, >= 0 (default 1000000; episode k uses seed + k)"
    )
    ev.add_argument("--suite", help="a suite file (eval/suites/<name>.toml): task, seeds and modes")
    ev.add_argument(
        "--workers",
        type=int,
        help="simulator workers (processes or Ray actors; default 1); results do not depend on it",
    )
    _executor_flags(ev)
    ev.add_argument(
        "--batch-size",
        dest="batch_size",
        type=int,
        default=1,
        help="episodes each worker runs in lockstep, one policy call a step for all of them (default 1)",
    )
    ev.add_argument(
        "--policy-option",
        dest="policy_option",
        action="append",
        metavar="KEY=VALUE",
        help="set a lerobot checkpoint's config field for this run (repeatable), e.g. temporal_ensemble_coeff=0.01, "
        "n_action_steps=5, num_inference_steps=10; the report lists them",
    )
    ev.add_argument(
        "--device",
        default="auto",
        help="where a lerobot policy's network runs: auto (default: CUDA when torch sees it), cpu or cuda",
    )
    ev.add_argument("--videos", type=int, default=0, help="episodes to film, failures and successes both (default 0)")
    ev.add_argument("--out", help="report folder (default outputs/eval/<task>/<policy>)")
    ev.add_argument(
        "--overwrite", action="store_true", help="replace an existing report in --out (and --save-dataset's dataset)"
    )
    ev.add_argument(
        "--save-dataset",
        dest="save_dataset",
        metavar="DIR",
        help="also store the scored episodes as a LeRobot dataset in DIR (frames, actions, rewards, a dataset card)",
    )
    ev.add_argument(
        "--obs-mode",
        dest="obs_mode",
        help="state (default), any camera mode (rgb, rgbd, depth, segmentation, '+'-joined) or pointcloud; a trained "
        "policy implies the mode its dataset was recorded in",
    )
    ev.add_argument(
        "--control-mode",
        dest="control_mode",
        help="default pd_joint_delta_pos, or the mode a lerobot/replay policy was trained in",
    )
    ev.add_argument("--reward-mode", dest="reward_mode", help="reward summed into returns (default dense)")
    ev.add_argument("--robot", help="one of the task's robots (default: the suite's, else the task's first)")
    ev.add_argument(
        "--settle-steps",
        dest="settle_steps",
        type=int,
        help="steps an episode runs on after its first success (default: the suite's, else 0); above 0 the "
        "headline metric is success_at_end instead of success_once",
    )
    ev.set_defaults(func=_eval)
    cmp = sub.add_parser(
        "compare",
        help="compare two eval reports of one suite: success difference with its 95%% CI and p-value, and a verdict",
    )
    cmp.add_argument("a", metavar="A", help="the baseline: a report.json (or its report folder)")
    cmp.add_argument("b", metavar="B", help="the candidate: a report.json (or its report folder)")
    cmp.add_argument("--alpha", default="0.05", help="significance level, between 0 and 1 (default 0.05)")
    cmp.add_argument(
        "--test",
        default="fisher",
        help="unpaired test: fisher (default) or barnard (more powerful, slower); when both reports scored the "
        "same seeds the headline is McNemar's paired test",
    )
    cmp.add_argument("--json", help="also write the comparison to this JSON file")
    cmp.add_argument(
        "--allow-different-suites",
        dest="allow_different_suites",
        action="store_true",
        help="compare reports whose task, seeds or modes differ (with a warning) instead of refusing",
    )
    cmp.add_argument(
        "--fail-if-worse",
        dest="fail_if_worse",
        action="store_true",
        help="exit 1 when B's success rate is significantly lower than A's (default: exit 0 whatever the verdict)",
    )
    cmp.set_defaults(func=_compare)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
