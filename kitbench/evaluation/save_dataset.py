"""`kitbench eval --save-dataset`: the checks before a run saves its scored episodes, and the LeRobot dataset
written from them once the run is scored."""

from __future__ import annotations

from pathlib import Path

from kitbench.errors import KitbenchError
from kitbench.evaluation.config import EvalConfig
from kitbench.evaluation.suite import Suite
from kitbench.evaluation.work import make_suite_env
from kitbench.metadata import is_recording


def saving(config: EvalConfig) -> bool:
    return config.output.save_dataset is not None


def check_save_dataset(config: EvalConfig, resuming: bool = False) -> None:
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


def write_dataset(config: EvalConfig, suite: Suite, episodes: list) -> None:
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
