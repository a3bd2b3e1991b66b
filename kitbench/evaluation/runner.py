"""Run a policy over a suite's seeds on the rollout engine (`kitbench.engine`: this process, a local process pool
or Ray actors), write the report, then film a few episodes.

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
from pathlib import Path
from typing import Any

from kitbench import faults
from kitbench.engine import RolloutEngine, make_executor
from kitbench.engine.executor import ClusterLost
from kitbench.env_settings import canonical_size
from kitbench.envs.interface import as_kitbench
from kitbench.errors import KitbenchError, one_line
from kitbench.evaluation.compare_inputs import seeds_text
from kitbench.evaluation.config import COMMAND_LINE, EvalConfig
from kitbench.evaluation.episode import EpisodeResult
from kitbench.evaluation.journal import EvalJournal
from kitbench.evaluation.provenance import outcome_differences, plain, provenance
from kitbench.evaluation.suite import Suite
from kitbench.evaluation.work import Batch, EvalWork, Film, Save, Trial, make_suite_env, suite_env_settings
from kitbench.metadata import is_recording
from kitbench.recording.stops import Stopped, StopSignals

REPORT_JSON, REPORT_MD, PLOTS_DIR, VIDEOS_DIR = "report.json", "report.md", "plots", "videos"


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


# -- the evaluation --------------------------------------------------------------------------------
def pick_video_seeds(results: list[EpisodeResult], count: int) -> list[EpisodeResult]:
    """`count` episodes to film, failures and successes both: half of each (the first ones by seed order),
    the other kind filling in when one runs short."""
    if count <= 0:
        return []
    failures = [r for r in results if not r.success]
    successes = [r for r in results if r.success]
    n_fail = min(len(failures), max(count - len(successes), (count + 1) // 2))
    chosen = {id(r) for r in failures[:n_fail] + successes[: count - n_fail]}
    return [r for r in results if id(r) in chosen]


def check_out_folder(out: Path, overwrite: bool, resume: bool = False) -> None:
    """Refuse a report folder that is not a folder, that holds something already (unless `overwrite`), that holds
    an interrupted evaluation (unless `resume` or `overwrite`), or a finished one to `resume`."""
    if out.exists() and not out.is_dir():
        raise KitbenchError(
            f"report folder {out} is a file; --out must be a folder (new, empty, or a report with --overwrite)"
        )
    if resume and overwrite:
        raise KitbenchError("--resume and --overwrite exclude each other: continue the evaluation, or start it again")
    journal = EvalJournal(out)
    if journal.exists():
        if not (resume or overwrite):
            raise KitbenchError(
                f"report folder {out} holds an interrupted evaluation ({journal.count()} episodes scored); continue "
                "it with --resume, or pass --overwrite to start again"
            )
        return
    if resume and (out / REPORT_JSON).is_file():
        raise KitbenchError(
            f"report folder {out} holds a finished evaluation: nothing to resume (pass --overwrite to run it again)"
        )
    if out.is_dir() and not overwrite and any(out.iterdir()):
        raise KitbenchError(f"report folder {out} exists; pass --overwrite to replace it")


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
        _check_save_dataset(config, resuming=stored is not None)
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
    plan = Plan(suite, timestep, fps, device, found, _resume_settings(config, suite, found))
    plan.provenance_seconds = time.monotonic() - started
    if stored is not None:
        differences = _resume_differences(stored["settings"], plan.settings)
        if differences:
            raise KitbenchError(
                f"cannot resume {config.out}: " + "; ".join(differences) + " (run it with the journal's settings, "
                "or pass --overwrite to start again)"
            )
        plan.resume, plan.provenance = True, stored["provenance"]  # the report's is the run that started it
        plan.journaled = journal.read([_seeds(job) for job in _jobs(suite, batch_size, saving=_saving(config))])
        if _saving(config):  # a line is written after its episode: only a damaged episode file can be missing
            whole = set(journal.episodes.check()[0])
            plan.journaled = list(takewhile(lambda r: r[0].seed in whole, plan.journaled))
    return plan


def _saving(config: EvalConfig) -> bool:
    return config.output.save_dataset is not None


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
    if _saving(config):
        raise KitbenchError(
            f"--stop-after {config.output.stop_after} leaves the run open and --save-dataset writes its dataset "
            "once, at the end: drop one of them"
        )


def _stop_after(config: EvalConfig) -> int | None:
    """How many of the suite's seeds this run scores, when fewer than all of them."""
    limit = config.output.stop_after
    return limit if limit is not None and limit < len(config.suite.seeds) else None


def journaled_results(config: EvalConfig) -> list[EpisodeResult]:
    """The nominal episodes the journal in `config.out` holds whole, in seed order (none without a journal):
    what an interrupted run has scored, read without running anything."""
    journal = EvalJournal(config.out)
    if journal.settings() is None:
        return []
    jobs = _jobs(config.suite, config.policy.batch_size, saving=_saving(config))
    done = journal.read([_seeds(job) for job in jobs])
    return [r for job, scored in zip(jobs, done, strict=False) if _condition(job) is None for r in scored]


def _first_jobs(seeds: int, batch_size: int) -> int:
    """How many jobs hold the first `seeds` seeds of a suite without perturbations (a batch: `batch_size` seeds)."""
    return -(-seeds // batch_size)


def _resume_settings(config: EvalConfig, suite: Suite, found: dict) -> dict:
    """What decides a run's scores, which a resumed run must share with the run it continues (the executor and
    its workers do not decide them, nor do the videos)."""
    checkpoint = found["policy"]["checkpoint"]
    return plain(
        {
            "policy": config.policy.policy,
            "checkpoint": None if checkpoint is None else checkpoint["files"],
            "suite": {k: v for k, v in suite.to_dict().items() if k not in ("name", "description", "source")},
            "execution": found["execution"],
            "software": found["software"],
            "save_dataset": None if config.output.save_dataset is None else str(Path(config.output.save_dataset)),
        }
    )


def _resume_differences(journaled: dict, now: dict) -> list[str]:
    """How the command differs from the journal's run, one phrase each, naming both values."""
    found = [
        f"{key.replace('_', '-')}: journal {journaled.get(key)!r}, now {now[key]!r}"
        for key in ("policy", "save_dataset")
        if journaled.get(key) != now[key]
    ]
    old, new = journaled.get("checkpoint") or {}, now["checkpoint"] or {}
    for name in dict.fromkeys([*old, *new]):
        if old.get(name) != new.get(name) and journaled.get("policy") == now["policy"]:
            short = [None if d is None else d[:12] for d in (old.get(name), new.get(name))]
            found.append(f"checkpoint file {name}: journal sha256 {short[0]}, now {short[1]}")
    old_suite, new_suite = journaled.get("suite") or {}, now["suite"]
    for key in dict.fromkeys([*old_suite, *new_suite]):
        a, b = old_suite.get(key), new_suite.get(key)
        if a != b:
            shown = (seeds_text(a or []), seeds_text(b or [])) if key == "seeds" else (repr(a), repr(b))
            found.append(f"suite {key}: journal {shown[0]}, now {shown[1]}")
    found += outcome_differences(
        {k: journaled.get(k) for k in ("execution", "software")},
        {k: now[k] for k in ("execution", "software")},
        ("journal", "now"),
    )
    return found


def _seeds(job: int | Trial | Batch | Save) -> tuple[int, ...]:
    if isinstance(job, Batch):
        return job.seeds
    return (job if isinstance(job, int) else job.seed,)


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
    jobs = _jobs(suite, batch_size, saving=_saving(config))
    stop_after = _stop_after(config)
    if stop_after is not None:  # the first seeds now, the journal kept for --resume to go on from
        jobs = jobs[: _first_jobs(stop_after, batch_size)]
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
            results, perturbed, episodes = _score(engine, suite, jobs, journaled, journal, progress)
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
            _write_dataset(config, suite, episodes)
        scored = time.monotonic()
        reported_suite = suite if stop_after is None else suite.first(stop_after)
        results = results[: len(reported_suite.seeds)]  # a batch may run past the seeds asked for
        report = _write_report(reported_suite, config.policy.policy, results, timestep, out, perturbed, options)
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
        _save(report, out)
        faults.point("eval.reported")
        chosen = pick_video_seeds(results, config.output.videos)
        if chosen:
            try:
                _film(engine, chosen, out, fps, report["output"]["videos"], progress)
            except Exception as exc:  # noqa: BLE001 - the scores stand whatever stops the videos; the report says why
                report["output"]["video_error"] = _video_error(exc)
            now = time.monotonic()
            report["timing"]["video_seconds"] = now - reported
            report["timing"]["seconds"] = now - wall_start
            _save(report, out)
        if stop_after is None:
            faults.point("eval.finishing")
            journal.remove()
    return report


def _jobs(suite: Suite, batch_size: int = 1, saving: bool = False) -> list[int | Trial | Batch | Save]:
    """The nominal seeds, then every seed under each perturbation and level (`suite.conditions`): one job a seed,
    or with `batch_size` > 1 one `Batch` per `batch_size` consecutive seeds of a condition; `saving`: the nominal
    seeds as `Save` jobs, whose episodes come back with their frames."""
    if batch_size > 1:
        seeds = suite.seeds
        return [
            Batch(tuple(seeds[i : i + batch_size]), condition)
            for condition in suite.conditions
            for i in range(0, len(seeds), batch_size)
        ]
    jobs: list[int | Trial | Batch | Save] = [Save(s) for s in suite.seeds] if saving else list(suite.seeds)
    for condition in suite.conditions[1:]:
        assert condition is not None
        jobs += [Trial(seed, *condition) for seed in suite.seeds]
    return jobs


def _condition(job: int | Trial | Batch | Save) -> tuple[str, float] | None:
    if isinstance(job, Trial):
        return (job.perturbation, job.level)
    return job.condition if isinstance(job, Batch) else None


def _score(
    engine: RolloutEngine,
    suite: Suite,
    jobs: list[int | Trial | Batch | Save],
    journaled: list[list[EpisodeResult]],
    journal: EvalJournal,
    progress: bool,
) -> tuple[list[EpisodeResult], dict[tuple[str, float], list[EpisodeResult]], list]:
    """The nominal results, the results under each (perturbation, level), in seed order, and the episodes the `Save`
    jobs kept: the first jobs' from the journal (`journaled`), the others run, each journaled as it comes back."""
    bar = None
    if progress:
        from kitbench.progress import progress as progress_bar

        bar = progress_bar(sum(len(_seeds(job)) for job in jobs), f"eval {suite.task}")
    results: list[EpisodeResult] = []
    perturbed: dict[tuple[str, float], list[EpisodeResult]] = {}
    episodes: list = []

    def take(job, scored: list[EpisodeResult]) -> None:
        condition = _condition(job)
        (results if condition is None else perturbed.setdefault(condition, [])).extend(scored)
        if bar is not None:
            bar.update(len(scored))
            if condition is None:
                bar.set_postfix(success=f"{sum(r.success for r in results) / len(results):.0%}")
            else:
                bar.set_postfix(condition=f"{condition[0]}={condition[1]:g}")

    try:
        for job, scored in zip(jobs, journaled, strict=False):
            if isinstance(job, Save):
                episodes.append(journal.episodes.load(job.seed)[0])
            take(job, scored)
        left = jobs[len(journaled) :]
        # SIGTERM and SIGHUP end the run as Ctrl-C does, never in the middle of journaling a finished job
        with StopSignals() as stops:
            for index, (job, result) in enumerate(zip(left, engine.map(left), strict=True), len(journaled)):
                episode = None
                if isinstance(job, Save):
                    result, episode = result
                    episodes.append(episode)
                scored = result if isinstance(job, Batch) else [result]
                with stops.storing():
                    journal.add(index, scored, episode)
                take(job, scored)
    finally:
        if bar is not None:
            bar.close()
    return results, perturbed, episodes


def _check_save_dataset(config: EvalConfig, resuming: bool = False) -> None:
    """`resuming`: the dataset folder may hold what the interrupted run saved (a kitbench dataset), replaced."""
    target = Path(config.output.save_dataset)  # type: ignore[arg-type]  # checked by the caller
    if config.policy.batch_size != 1:
        raise KitbenchError(
            f"--save-dataset records episodes one at a time; drop --batch-size {config.policy.batch_size}"
        )
    from kitbench.recording.dataset import recover

    recover(target)  # a save a kill interrupted: its last commit back in place, an unfinished session gone
    if target.exists() and not (config.output.overwrite or resuming):
        raise KitbenchError(f"dataset folder {target} exists; pass --overwrite to replace it")
    if target.exists() and not is_recording(target):
        raise KitbenchError(f"{target} is not a kitbench dataset; --overwrite replaces only those")


def _write_dataset(config: EvalConfig, suite: Suite, episodes: list) -> None:
    """The scored episodes as a LeRobot dataset (with its card), committed once: it appears whole or not at all."""
    import shlex

    import kitbench
    from kitbench.metadata import ACTION_CONVENTION, RecordingInfo, expert_options
    from kitbench.recording.features import dataset_features
    from kitbench.recording.session import RecordingSession

    target = Path(config.output.save_dataset)  # type: ignore[arg-type]  # only called with one
    env = make_suite_env(suite)
    try:
        env.reset(seed=suite.seeds[0])
        features, fps, robot = dataset_features(env), env.control_freq, env.robot_uid
    finally:
        env.close()
    policy = config.policy.policy
    flags = ["--suite", suite.source] if suite.source else ["--task", suite.task, "--seed", str(suite.seeds[0])]
    flags += ["--episodes", str(len(suite.seeds)), "--policy", policy, "--obs-mode", suite.obs_mode]
    flags += ["--control-mode", suite.control_mode, "--robot", robot, "--settle-steps", str(suite.settle_steps)]
    cameras = suite.obs_mode != "state"  # the size and framing the frames' images were rendered in
    if cameras and suite.camera_size is not None:
        flags += ["--camera-size", suite.camera_size]
    if cameras and suite.camera_view is not None:
        flags += ["--camera-view", suite.camera_view]
    for key, value in config.policy.policy_options:
        flags += ["--policy-option", f"{key}={value}"]
    info = RecordingInfo(
        task=suite.task_id,
        seed=suite.seeds[0],
        seeds=list(suite.seeds),
        obs_mode=suite.obs_mode,
        control_mode=suite.control_mode,
        policy=policy,
        expert_options=expert_options(policy, config.policy.policy_options),
        settle_steps=suite.settle_steps,
        reward_mode=suite.reward_mode,
        robot=robot,
        camera_size=suite.camera_size if cameras else None,
        camera_view=suite.camera_view if cameras else None,
        kitbench_version=kitbench.__version__,
        action_convention=ACTION_CONVENTION,
        repo_id=f"kitbench/{suite.task}",
        fps=fps,
        made_by=shlex.join(["kitbench", "eval", *flags, "--save-dataset", "<folder>"]),
    )
    # an existing dataset (--overwrite) is replaced by the commit, in one rename: a kill before leaves it whole
    session = RecordingSession(target, info, features, robot, commit_interval=float("inf"), durable=False, replace=True)
    session.start()
    try:
        for episode in episodes:
            session.store(episode)
        session.commit()
    except BaseException:
        session.abandon()
        raise


def _write_report(
    suite: Suite,
    policy: str,
    results: list[EpisodeResult],
    timestep: float,
    out: Path,
    perturbed: dict[tuple[str, float], list[EpisodeResult]] | None = None,
    policy_options: dict | None = None,
) -> dict:
    from kitbench.evaluation.plots import write_plots
    from kitbench.evaluation.report import build_report

    report = build_report(suite, policy, results, timestep, perturbed)
    if policy_options:
        report["policy_options"] = dict(policy_options)
    report["output"] = {"videos": []}
    report["output"]["plots"] = [str(p.relative_to(out)) for p in write_plots(report, out / PLOTS_DIR)]
    return report


def _save(report: dict, out: Path) -> None:
    from kitbench.evaluation.report import markdown, write_json

    (out / REPORT_MD).write_text(markdown(report))
    write_json(report, out / REPORT_JSON)  # last: a report.json means the report.md beside it is complete


def _film(
    engine: RolloutEngine, chosen: list[EpisodeResult], out: Path, fps: int, videos: list[dict], progress: bool
) -> None:
    """Replay and film `chosen`, appending each video to `videos` as soon as it is written (so the ones made
    before a failure stay listed)."""
    bar = None
    if progress:  # filming renders every step: seconds a video on a CPU, so it gets a bar of its own
        from kitbench.progress import progress as progress_bar

        bar = progress_bar(len(chosen), "videos")
    try:
        _film_each(engine, chosen, out, fps, videos, bar)
    finally:
        if bar is not None:
            bar.close()


def _film_each(engine: RolloutEngine, chosen: list[EpisodeResult], out: Path, fps: int, videos: list[dict], bar):
    for scored, (replayed, mp4) in zip(chosen, engine.map(Film(r.seed, fps) for r in chosen), strict=True):
        path = out / VIDEOS_DIR / f"seed{scored.seed}_{'success' if scored.success else 'failure'}.mp4"
        path.parent.mkdir(parents=True, exist_ok=True)
        partial = path.with_name(f".{path.name}.partial")
        partial.write_bytes(mp4)
        partial.replace(path)  # a video under its name is whole
        faults.point("eval.filmed")
        same = (replayed.success, replayed.length, replayed.episode_return) == (
            scored.success,
            scored.length,
            scored.episode_return,
        )
        videos.append(
            {
                "seed": scored.seed,
                "success": scored.success,
                "failure": scored.failure,
                "path": str(path.relative_to(out)),
                "matches_scored_episode": same,
            }
        )
        if bar is not None:
            bar.update(1)


def _video_error(exc: Exception) -> str:
    """One line on why the videos could not be made: `kitbench doctor`'s line when this machine has no render
    device, else the exception's type and first line."""
    from kitbench.doctor import vulkan_error

    no_device = vulkan_error()
    if no_device is not None:
        return no_device
    return one_line(exc)


def summary_lines(report: dict, out: Path) -> list[str]:
    s = report["success"]
    lines = [
        (
            f"{report['task']} · {report['policy']} · {report['episodes']} episodes: success {s['rate']:.1%} "
            f"(95% CI {s['ci95'][0]:.1%}–{s['ci95'][1]:.1%}; {report.get('headline', 'success_once')})"
        )
    ]
    if report.get("headline") == "success_at_end":
        lines.append(f"  success_once: {report['success_once']['rate']:.1%}")
    for name, r in report["criteria"].items():
        lines.append(f"  {name}: {r['rate']:.1%}")
    failures = {k: v for k, v in report["failure_categories"].items() if v}
    if failures:
        lines.append("  failures: " + ", ".join(f"{k} {v}" for k, v in failures.items()))
    lines.extend(
        f"  {c['perturbation']} {c['level']:g} {c['unit']}: {c['success']['rate']:.1%} "
        f"({c['vs_nominal']['difference']:+.1%}, p {c['vs_nominal']['p_value']:.2g})"
        for c in report.get("robustness", [])
    )
    if report.get("partial"):
        lines.append(
            f"  stopped after the first {report['partial']['episodes']} of the suite's "
            f"{report['partial']['suite_episodes']} seeds: --resume scores on (the journal is kept)"
        )
    lines.append(
        f"  report: {out / REPORT_MD} (+ {REPORT_JSON}, {len(report['output']['plots'])} plots, "
        f"{len(report['output']['videos'])} videos)"
    )
    return lines
