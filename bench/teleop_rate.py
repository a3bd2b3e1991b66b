"""Real-time pacing of a teleoperated recording with the live view on: `python bench/teleop_rate.py [--seconds 120]
[--tasks LiftPegUpright-v1,AssemblingKits-v1] [--obs-mode rgb] [--display rerun|none] [--scene PIXELS] [--keep DIR]`.

Per task, on the SO-101 with its two cameras (rgb, 128x128) in `pd_joint_pos`: a scripted leader arm (a LeRobot
teleoperator registered in lerobot's `TeleoperatorConfig` registry, built by lerobot's factory, as a device plugin
is) replays the task's expert, seed after seed, each from the simulated arm's start pose, through kitbench's teleop
source into `kitbench record`: real-time pacing, the episode keys, MCAP logs, the journal and commits, and the Rerun
live view (every camera, the third-person view, the state and the action, lerobot's `log_rerun_data`) written to an
.rrd file, as a person without a display would watch it. The session lasts about `--seconds` (episodes are added
until their steps fill it at the control rate).

Printed per task: the step-to-step interval (between the device's reads inside an episode, which the teleop source
makes right after each paced release) as median, p99 and max against the control period, whether p99 is within 10%
of it, the late releases, the episodes and successes, and the .rrd's size. The teleop source's own line (its pacer's
intervals) is printed by the recording as it ends. A 10-second smoke run: `--seconds 10`.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np
from lerobot.teleoperators import Teleoperator, TeleoperatorConfig

from kitbench.cli import main as kitbench
from kitbench.envs.features import STATE, observation_frame
from kitbench.policies.registry import make_policy, policy_source
from kitbench.registration import make_env, task_entry
from kitbench.rollout import Hook, OneEpisode, run

ROBOT, MODE, DEVICE = "so101", "pd_joint_pos", "kitbench_bench_arm"
MOTORS = ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll", "gripper")
WITHIN = 0.10  # the target: p99 within 10% of the control period


@dataclass
class Episode:
    start: dict[str, float]  # the simulated arm's start pose, where the person brings the leader first
    actions: list[dict[str, float]]  # the expert's joint targets, one a step


class Capture(Hook):
    def __init__(self) -> None:
        self.start: np.ndarray | None = None
        self.actions: list[np.ndarray] = []

    def on_reset(self, episode) -> None:
        self.start = observation_frame(episode.env, episode.obs)[STATE]

    def on_action(self, episode, action, executed) -> None:
        self.actions.append(executed.copy())


def expert_streams(task: str, seconds: float) -> tuple[list[Episode], float]:
    """The expert's episodes from seed 0 on, until their steps fill `seconds` at the control rate (state
    observations: the physics, and so the joint stream, are the rendering env's)."""
    env = make_env(task, obs_mode="state", control_mode=MODE, robot_uids=ROBOT)
    period = env.control_timestep
    names = [f"{m}.pos" for m in MOTORS]
    episodes: list[Episode] = []
    steps = 0
    try:
        while steps * period < seconds or not episodes:
            capture = Capture()
            run([env], [len(episodes)], OneEpisode(make_policy("expert")), lambda _, c=capture: [c])
            assert capture.start is not None
            start = dict(zip(names, map(float, capture.start), strict=True))
            actions = [dict(zip(names, map(float, a), strict=True)) for a in capture.actions]
            episodes.append(Episode(start, actions))
            steps += len(actions)
    finally:
        env.close()
    return episodes, period


@TeleoperatorConfig.register_subclass(DEVICE)
@dataclass
class BenchArmConfig(TeleoperatorConfig):
    port: str = "/dev/kitbench-bench"


class BenchArm(Teleoperator):
    """Plays `STREAM` read by read: each episode's start pose (read while the source waits for the start pose),
    then its joint targets; times the reads inside episodes."""

    config_class = BenchArmConfig
    name = DEVICE
    stream: ClassVar[list[Episode]] = []
    intervals: ClassVar[list[float]] = []

    def __init__(self, config: BenchArmConfig):
        super().__init__(config)
        self.connected = False
        self.episode, self.step = 0, -1  # step -1: the start pose comes next
        self.last: float | None = None

    @property
    def action_features(self) -> dict:
        return {f"{m}.pos": float for m in MOTORS}

    @property
    def feedback_features(self) -> dict:
        return {}

    @property
    def is_connected(self) -> bool:
        return self.connected

    def connect(self, calibrate: bool = True) -> None:
        self.connected = True

    @property
    def is_calibrated(self) -> bool:
        return True

    def calibrate(self) -> None:
        pass

    def configure(self) -> None:
        pass

    def get_action(self) -> dict[str, float]:
        now = time.perf_counter()
        current = self.stream[min(self.episode, len(self.stream) - 1)]
        if self.step < 0:
            self.step, self.last = 0, None
            return dict(current.start)
        if self.last is not None:
            self.intervals.append(now - self.last)
        self.last = now
        action = current.actions[min(self.step, len(current.actions) - 1)]
        self.step += 1
        if self.step == len(current.actions):
            self.episode, self.step = self.episode + 1, -1
        return dict(action)

    def send_feedback(self, feedback: dict) -> None:
        pass

    def disconnect(self) -> None:
        self.connected = False


VIEW: dict[str, object] = {}  # the teleop source's view options for this run


@policy_source("bench_teleop")
def _bench_teleop(argument: str | None, device: str, options: dict):
    from kitbench.policies.teleop import TeleopPolicy

    return TeleopPolicy(DEVICE, dict(VIEW))


def run_task(task: str, seconds: float, obs_mode: str, display: str, scene: int | None, folder: Path) -> dict:
    episodes, period = expert_streams(task, seconds)
    BenchArm.stream, BenchArm.intervals = episodes, []
    rrd = folder / f"{task}.rrd"
    VIEW.clear()
    VIEW.update({"display": display} | ({"display_save": str(rrd)} if display == "rerun" else {}))
    # a person's episode has no step limit: the expert's unsuccessful ones end where the task's limit ends them
    VIEW["max_seconds"] = task_entry(task).env_class.episode_steps(ROBOT) * period
    if scene is not None:
        VIEW["display_scene"] = scene
    out = folder / task
    # fmt: off
    argv = ["record", "--task", task, "--robot", ROBOT, "--control-mode", MODE, "--obs-mode", obs_mode,
            "--episodes", str(len(episodes)), "--out", str(out), "--policy", "bench_teleop"]
    # fmt: on
    started = time.perf_counter()
    code = kitbench(argv)
    wall = time.perf_counter() - started
    values = np.asarray(BenchArm.intervals)
    p99 = float(np.percentile(values, 99))
    return {
        "task": task,
        "exit": code,
        "episodes": len(episodes),
        "steps": len(values) + len(episodes),
        "wall": wall,
        "period": period,
        "median": float(np.median(values)),
        "p99": p99,
        "max": float(values.max()),
        "late": int((values > 1.5 * period).sum()),
        "within": p99 <= (1 + WITHIN) * period,
        "rrd": rrd.stat().st_size / 2**20 if rrd.exists() else 0.0,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=120.0, help="session length per task (s)")
    parser.add_argument("--tasks", default="LiftPegUpright-v1,AssemblingKits-v1")
    parser.add_argument("--obs-mode", default="rgb")
    parser.add_argument("--display", default="rerun", choices=("rerun", "none"))
    parser.add_argument(
        "--scene",
        type=int,
        default=None,
        help="the view's third-person image, pixels (0: none; default: the teleop source's, none beside cameras)",
    )
    parser.add_argument("--keep", type=Path, default=None, help="keep the datasets and .rrd files in this folder")
    args = parser.parse_args()
    folder = args.keep or Path(tempfile.mkdtemp(prefix="kitbench-teleop-rate-"))
    folder.mkdir(parents=True, exist_ok=True)
    try:
        rows = [
            run_task(t, args.seconds, args.obs_mode, args.display, args.scene, folder) for t in args.tasks.split(",")
        ]
    finally:
        if args.keep is None:
            shutil.rmtree(folder, ignore_errors=True)
    print(f"\nteleoperated, {ROBOT} {MODE}, obs {args.obs_mode}, view {args.display}, ~{args.seconds:g} s a task")
    header = f"{'task':<20} {'eps':>4} {'steps':>6} {'wall s':>7} {'period':>7} {'median':>7} {'p99':>7} {'max':>7}"
    print(header + f" {'late':>5} {'p99<=+10%':>9} {'rrd MiB':>8}")
    for r in rows:
        ms = {k: f"{1e3 * r[k]:.1f}" for k in ("period", "median", "p99", "max")}
        print(
            f"{r['task']:<20} {r['episodes']:>4} {r['steps']:>6} {r['wall']:>7.1f} {ms['period']:>7} {ms['median']:>7} "
            f"{ms['p99']:>7} {ms['max']:>7} {r['late']:>5} {'yes' if r['within'] else 'NO':>9} {r['rrd']:>8.1f}"
        )
    return 0 if all(r["exit"] == 0 for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
