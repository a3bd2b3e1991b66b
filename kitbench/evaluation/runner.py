"""Run an evaluation: check the request first (`validate`: the suite fitted to the policy, the report folder, a
resumed run's journal), then run the policy over the suite's seeds on the rollout engine (`kitbench.engine`: this
process, a local process pool or Ray actors), write the report, then film a few episodes.

Episodes are scored without rendering unless the policy itself looks at images. Videos are made afterwards by
replaying the chosen seeds in an env that renders: episodes are deterministic in their seed, so the filmed
episode is the scored one (the report says so per video, having checked outcome, length and return). The report
is written before the videos are made, so a machine that cannot render (no Vulkan device) still gets its scores:
the report then says why there are no videos (`output.video_error`).
"""

from __future__ import annotations

import shutil
import time
from contextlib import nullcontext
from dataclasses import asdict, dataclass, field, replace
from itertools import takewhile
from typing import Any

from kitbench import faults
from kitbench.engine import RolloutEngine, make_executor
from kitbench.engine.executor import ClusterLost
from kitbench.env_settings import canonical_size
from kitbench.envs.interface import as_kitbench
from kitbench.errors import KitbenchError
from kitbench.evaluation.config import COMMAND_LINE, EvalConfig
from kitbench.evaluation.episode import EpisodeResult
from kitbench.evaluation.filming import film, pick_video_seeds, video_error
from kitbench.evaluation.jobs import first_jobs, job_seeds, score, suite_jobs
from kitbench.evaluation.journal import EvalJournal
from kitbench.evaluation.output import PLOTS_DIR, REPORT_JSON, REPORT_MD, VIDEOS_DIR, save_report, write_report
from kitbench.evaluation.provenance import provenance
from kitbench.evaluation.resume import check_out_folder, resume_differences, resume_settings
from kitbench.evaluation.save_dataset import check_save_dataset, saving, write_dataset
from kitbench.evaluation.suite import Suite
from kitbench.evaluation.work import EvalWork, make_suite_env, suite_env_settings
from kitbench.recording.stops import Stopped


def fit_suite_to_policy(suite: Suite, policy, origins: dict[str, str]) -> Suite:
    """Apply what a policy needs (its requirements: task / obs_mode / control_mode / robot) to the suite, or explain
    the conflict (`origins`: where each env setting came from; the command line's are not silently changed). An
    action means nothing in the wrong control mode, so that one is never silently changed."""
    from kitbench.policies.base import requirements_of

    explicit = {name for name, origin in origins.items() if origin == COMMAND_LINE}
    needs = requirements_of(policy)
    task = needs.get("task")
    if task is not None and task != suite.task:
        raise KitbenchError(
            f"policy {policy.name} was recorded on {task} but this evaluation runs {suite.task}; "
            f"evaluate it with --task {task}"
        )
    changes: dict[str, Any] = {}
    robot = needs.get("robot")
    if robot is not None and robot != suite.robot_uid:
        # an action means a joint target of one robot: never silently another robot's
        if "robot" in explicit or suite.robot is not None:
            raise KitbenchError(
                f"policy {policy.name} was trained on robot {robot} but this evaluation runs {suite.robot_uid}; "
                f"evaluate it with --robot {robot}"
            )
        changes["robot"] = robot
    control = needs.get("control_mode")
    if control is not None and control != suite.control_mode:
        # A suite's control mode is for policies that act in any mode (expert, baselines): success does not depend
        # on it, and a trained policy's actions mean something in its own mode only. Asked for on the command
        # line, another mode is a mistake to point out.
        if "control_mode" in explicit:
            raise KitbenchError(
                f"policy {policy.name} was trained on {control} actions but the command line asks for "
                f"{suite.control_mode}; evaluate it with --control-mode {control}"
            )
        changes["control_mode"] = control
    obs = needs.get("obs_mode")
    if obs is not None and obs != suite.obs_mode:
        if "obs_mode" in explicit and suite.obs_mode == "state":
            raise KitbenchError(
                f"policy {policy.name} needs obs_mode {obs} (it reads cameras or a point cloud); --obs-mode "
                f"{suite.obs_mode} has none"
            )
        if suite.obs_mode == "state":
            changes["obs_mode"] = obs
    trained = needs.get("camera_size")
    if trained is not None and canonical_size(trained) != suite.camera_size:
        # images are never resized: a policy sees the cameras at the size it was trained at, or is not scored
        if suite.camera_size is not None:
            raise KitbenchError(
                f"policy {policy.name} was trained on {trained} camera images but this evaluation renders "
                f"{suite.camera_size}; evaluate it with --camera-size {trained}"
            )
        changes["camera_size"] = canonical_size(trained)
    view = needs.get("camera_view")
    if view != suite.camera_view and "obs_mode" in needs:  # a policy reading the cameras
        # cameras where they stood in training, or no score: a moved camera is another input, not a harder test
        if suite.camera_view is not None:
            learned = f"camera view {view}" if view else "the task's own camera views"
            fix = f"evaluate it with --camera-view {view}" if view else "drop --camera-view"
            raise KitbenchError(
                f"policy {policy.name} was trained on {learned} but this evaluation renders camera view "
                f"{suite.camera_view}; {fix}"
            )
        changes["camera_view"] = view
    return replace(suite, **changes) if changes else suite


@dataclass
class Plan:
    """What `validate` found: the suite fitted to the policy, the control step, the device, the provenance of the
    report, what a resume must match, and the results of the jobs a resumed run's journal holds."""

    suite: Suite
    timestep: float
    fps: int
    device: str
    provenance: dict
    settings: dict
    journaled: list[list[EpisodeResult]] = field(default_factory=list)
    resume: bool = False  # a journal with settings to continue
    provenance_seconds: float = 0.0


def validate(config: EvalConfig) -> Plan:
    """Every check that can fail before anything is written or run at length, a resumed run's journal against the
    command's settings included."""
    from kitbench.policies.lerobot_policy import resolve_device
    from kitbench.policies.registry import make_policy

    config.validate()
    _check_stop_after(config)
    device = resolve_device(config.policy.device)
    check_out_folder(config.out, config.output.overwrite, config.output.resume)
    journal = EvalJournal(config.out)
    stored = journal.settings() if config.output.resume and journal.exists() else None
    if config.output.save_dataset is not None:
        check_save_dataset(config, resuming=stored is not None)
    options = dict(config.policy.policy_options)
    policy = make_policy(config.policy.policy, device, options)
    suite = fit_suite_to_policy(config.suite, policy, config.origins)
    from kitbench.doctor import require_renderer
    from kitbench.envs.modes import IMAGE_OBS_MODES

    require_renderer(suite.obs_mode)
    env = make_suite_env(suite)
    try:
        obs, info = env.reset(seed=suite.seeds[0])
        policy.reset(env, suite.seeds[0], obs, info)  # policies check the env fits them here
        timestep = env.control_timestep
        fps = env.control_freq
        env_settings = {**suite_env_settings(suite), "sim": asdict(as_kitbench(env).sim_config)}
    finally:
        env.close()
    started = time.monotonic()
    renders = suite.obs_mode in IMAGE_OBS_MODES
    batch_size = config.policy.batch_size
    delay = config.policy.action_delay
    found = provenance(config.policy.policy, policy, suite, env_settings, device, batch_size, options, renders, delay)
    plan = Plan(suite, timestep, fps, device, found, resume_settings(config, suite, found))
    plan.provenance_seconds = time.monotonic() - started
    if stored is not None:
        differences = resume_differences(stored["settings"], plan.settings)
        if differences:
            raise KitbenchError(
                f"cannot resume {config.out}: " + "; ".join(differences) + " (run it with the journal's settings, "
                "or pass --overwrite to start again)"
            )
        plan.resume, plan.provenance = True, stored["provenance"]  # the report's is the run that started it
        plan.journaled = journal.read([job_seeds(job) for job in suite_jobs(suite, batch_size, saving=saving(config))])
        if saving(config):  # a line is written after its episode: only a damaged episode file can be missing
            whole = set(journal.episodes.check()[0])
            plan.journaled = list(takewhile(lambda r: r[0].seed in whole, plan.journaled))
    return plan


def _check_stop_after(config: EvalConfig) -> None:
    """`--stop-after` cuts the journal's job list at a seed: a robustness suite's jobs run every seed nominal first,
    and a dataset is written once, whole."""
    if _stop_after(config) is None:
        return
    if config.suite.perturbations:
        raise KitbenchError(
            f"--stop-after {config.output.stop_after} scores a prefix of the seeds; suite {config.suite.name} is a "
            "robustness suite, whose conditions run after every nominal seed: drop --stop-after"
        )
    if saving(config):
        raise KitbenchError(
            f"--stop-after {config.output.stop_after} leaves the run open and --save-dataset writes its dataset "
            "once, at the end: drop one of them"
        )


def _stop_after(config: EvalConfig) -> int | None:
    """How many of the suite's seeds this run scores, when fewer than all of them."""
    limit = config.output.stop_after
    return limit if limit is not None and limit < len(config.suite.seeds) else None


def eval_engine(config: EvalConfig, plan: Plan, jobs: int) -> RolloutEngine:
    """The engine an evaluation scores on (not started): the plan's suite and device, the policy with its options,
    on the executor `config` names with no more workers than `jobs`."""
    options = dict(config.policy.policy_options)
    work = EvalWork(plan.suite, config.policy.policy, plan.device, options, config.policy.action_delay)
    return RolloutEngine(make_executor(config.executor, max(1, jobs)), work)


def run_eval(config: EvalConfig, progress: bool = True, engine: RolloutEngine | None = None) -> dict:
    """Score the policy on every seed (each finished job journaled, so that `resume` continues a run that was
    stopped), write the report (report.json, report.md, plots), then make the videos and write the report again
    with them. A failed video pass leaves the report, with `output.video_error` saying why, and returns
    normally. `engine`: a started `eval_engine` of this config to score on, left running (a race scores every
    look on one); else one is started for the run and stopped after it."""
    wall_start = time.monotonic()
    plan = validate(config)
    suite, timestep, fps, device = plan.suite, plan.timestep, plan.fps, plan.device
    out = config.out
    start = time.monotonic()
    batch_size = config.policy.batch_size
    jobs = suite_jobs(suite, batch_size, saving=saving(config))
    stop_after = _stop_after(config)
    if stop_after is not None:  # the first seeds now, the journal kept for --resume to go on from
        jobs = jobs[: first_jobs(stop_after, batch_size)]
    journaled = plan.journaled[: len(jobs)]  # a journal may hold more than this run reports on: they stay in it
    journal = EvalJournal(out)
    # the workers start before the report folder is touched: a run whose workers cannot start changes nothing
    options = dict(config.policy.policy_options)
    own = eval_engine(config, plan, len(jobs) - len(journaled)) if engine is None else nullcontext(engine)
    with own as engine:
        if plan.resume:
            journal.open(len(plan.journaled))  # every whole line kept, a torn one cut off
        else:
            out.mkdir(parents=True, exist_ok=True)
            for stale in (REPORT_JSON, REPORT_MD):
                (out / stale).unlink(missing_ok=True)
            for stale in (PLOTS_DIR, VIDEOS_DIR):
                shutil.rmtree(out / stale, ignore_errors=True)
            journal.start(plan.settings, plan.provenance)
            journal.open(0)
            faults.point("eval.started")
        try:
            results, perturbed, episodes = score(engine, suite, jobs, journaled, journal, progress)
        except ClusterLost as exc:
            raise KitbenchError(
                f"{exc}; the episodes scored so far are kept: continue with --resume (the same command, on any "
                "cluster or --executor local)"
            ) from None
        except Stopped as exc:
            raise KitbenchError(
                f"stopped by {exc}: the episodes scored so far are kept in {journal.root}; continue with --resume"
            ) from None
        finally:
            journal.close()
        faults.point("eval.scored")
        if config.output.save_dataset is not None:
            write_dataset(config, suite, episodes)
        scored = time.monotonic()
        reported_suite = suite if stop_after is None else suite.first(stop_after)
        results = results[: len(reported_suite.seeds)]  # a batch may run past the seeds asked for
        report = write_report(reported_suite, config.policy.policy, results, timestep, out, perturbed, options)
        if stop_after is not None:
            report["partial"] = {"episodes": stop_after, "suite_episodes": len(suite.seeds)}
        report["provenance"] = plan.provenance
        reported = time.monotonic()
        # Wall time from the call to the report, and its parts: checking the setup (loading the policy, building
        # an env: seconds for a lerobot checkpoint), scoring (worker start-up included) and writing the report.
        # Episodes per minute are over the wall time; counting only the scoring, a 15.5 s run of a lerobot
        # checkpoint once printed 442 episodes/min.
        report["timing"] = {
            "seconds": reported - wall_start,
            "setup_seconds": start - wall_start,
            "scoring_seconds": scored - start,
            "report_seconds": reported - scored,
            "video_seconds": 0.0,
            "provenance_seconds": plan.provenance_seconds,
            "workers": engine.workers,
            "executor": config.executor.executor,
            "batch_size": batch_size,
            "device": device,
            "resumed_episodes": sum(len(r) for r in journaled),
            "episodes_per_minute": 60.0 * len(results) / max(reported - wall_start, 1e-9),
        }
        save_report(report, out)
        faults.point("eval.reported")
        chosen = pick_video_seeds(results, config.output.videos)
        if chosen:
            try:
                film(engine, chosen, out, fps, report["output"]["videos"], progress)
            except Exception as exc:  # noqa: BLE001 - the scores stand whatever stops the videos; the report says why
                report["output"]["video_error"] = video_error(exc)
            now = time.monotonic()
            report["timing"]["video_seconds"] = now - reported
            report["timing"]["seconds"] = now - wall_start
            save_report(report, out)
        if stop_after is None:
            faults.point("eval.finishing")
            journal.remove()
    return report
