"""LeRobot's own commands on the simulated SO-101 (`--robot.type=kitbench_so101`) as docs/teleoperation.md writes
them: the `lerobot-teleoperate`, `lerobot-record` and `lerobot-rollout` lines parsed from the docs and run in a
process each, offline, with a scripted leader arm (`tests.lerobot_scripted`); the recording's episodes reset at
LeRobot's boundaries only, without a jump inside, each one's seed stored; the servos' speed limit on a leader's jump;
the start-pose wait; the episode bookkeeping at lerobot-record's boundaries and re-record."""

from __future__ import annotations

import json
import logging
import math
import shlex
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from kitbench.envs.features import STATE, observation_frame
from kitbench.metadata import read_episodes
from kitbench.registration import make_env
from tests.lerobot_scripted import ROOT, play

DOC = ROOT / "docs" / "teleoperation.md"
SECTION = "## LeRobot's commands on the simulated arm"
LIFT = "LiftPegUpright-v1"
MOTORS = ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll", "gripper")
ARM = [f"{m}.pos" for m in MOTORS[:-1]]
# the STS3215's 4.7 rad/s (docs/robots.md) in degrees a 50 ms control step; a PD-driven joint overshoots its
# rate-limited target by a few percent
SERVO_STEP = math.degrees(4.7 * 0.05)
OVERSHOOT = 1.06
# what the tests change in the documented lines: a scripted leader for the real one, a folder of the test's, two
# 3-second episodes with a 1-second reset for the documented ones (a person's minutes), and the motors only where a
# line does not need the cameras (an rgb scene needs a Vulkan device, and seconds to build)
SCRIPTED = {"teleop.type": "kitbench_replay_arm"}
RECORD_OVERRIDES = {
    **SCRIPTED,
    "dataset.num_episodes": "2",
    "dataset.episode_time_s": "3",
    "dataset.reset_time_s": "1",
}
STATE_ONLY = "--robot.obs_mode=state"


# -- the documented lines ------------------------------------------------------------------------------------------
def doc_commands() -> dict[str, list[str]]:
    """The command lines of the docs' section on `kitbench_so101`, by command, as a shell splits them."""
    text = DOC.read_text()
    block = text[text.index(SECTION) :].split("```bash\n", 1)[1].split("```", 1)[0]
    lines = block.replace("\\\n", " ").splitlines()
    return {argv[0]: argv for argv in map(shlex.split, lines) if argv}


def flags(argv: list[str]) -> dict[str, str]:
    return dict(a[2:].split("=", 1) for a in argv[1:] if a.startswith("--") and "=" in a)


def replaced(argv: list[str], values: dict[str, str]) -> list[str]:
    """`argv` with the value of each flag in `values` replaced (each must be there)."""
    missing = set(values) - set(flags(argv))
    assert not missing, f"{argv[0]} line lacks {missing}"
    return [f"--{k}={values[k]}" if (k := a[2:].split("=", 1)[0]) in values else a for a in argv]


def test_the_documented_lines_are_offline_and_sized_for_the_tasks():
    commands = doc_commands()
    assert set(commands) == {"lerobot-teleoperate", "lerobot-record", "lerobot-rollout"}
    for argv in commands.values():
        assert flags(argv)["robot.type"] == "kitbench_so101"
    record = flags(commands["lerobot-record"])
    assert record["dataset.push_to_hub"] == "false" and record["dataset.root"]  # no Hub upload, a local folder
    assert record["teleop.id"] and flags(commands["lerobot-teleoperate"])["teleop.id"]  # its calibration file
    assert record["dataset.fps"] == "20"  # the tasks' control rate
    # a person's episode fits in the time: the task's own step limit (5 s on the SO-101) and more, not 60 s idle
    assert 10 <= float(record["dataset.episode_time_s"]) <= 60
    assert 1 <= float(record["dataset.reset_time_s"]) <= 15
    assert int(record["dataset.num_episodes"]) >= 1


# -- a scripted leader ---------------------------------------------------------------------------------------------
def start_poses(seeds: tuple[int, ...]) -> dict[int, np.ndarray]:
    env = make_env(LIFT, obs_mode="state", control_mode="pd_joint_pos", robot_uids="so101")
    try:
        return {seed: observation_frame(env, env.reset(seed=seed)[0])[STATE] for seed in seeds}
    finally:
        env.close()


def leader(pose: np.ndarray, pan: float = 0.0) -> dict[str, float]:
    return {f"{m}.pos": float(v) + (pan if m == "shoulder_pan" else 0.0) for m, v in zip(MOTORS, pose, strict=True)}


@pytest.fixture(scope="module")
def poses() -> dict[int, np.ndarray]:
    return start_poses((0, 1))


class Lines(logging.Handler):
    """The plugin's log lines."""

    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(record.getMessage())


@pytest.fixture(scope="module")
def recorded(tmp_path_factory, poses) -> tuple[Path, list[str]]:
    """The documented lerobot-record line, run for two episodes with a reset between; the leader starts 25 degrees
    off the start pose, comes to it, jumps 60 degrees in the pan and back, then rests at the start pose. A step limit
    of 30 (`--robot.episode_length`) falls while the arm is turned: a scene reset there would show."""
    where = tmp_path_factory.mktemp("record")
    start = poses[0]
    reads = [leader(start, 25.0)] * 10 + [leader(start)] * 20 + [leader(start, 60.0)] * 15 + [leader(start)]
    argv = replaced(doc_commands()["lerobot-record"], {**RECORD_OVERRIDES, "dataset.root": str(where / "sim")})
    plugin = logging.getLogger("lerobot_robot_kitbench")
    lines, level = Lines(), plugin.level
    plugin.addHandler(lines)
    plugin.setLevel(logging.INFO)
    try:
        with pytest.MonkeyPatch.context() as patch:
            play([*argv, STATE_ONLY, "--robot.episode_length=30"], {"reads": reads}, patch)
    finally:
        plugin.removeHandler(lines)
        plugin.setLevel(level)
    return where / "sim", lines.lines


def frames(root: Path) -> pd.DataFrame:
    data = pd.concat(pd.read_parquet(f) for f in sorted((root / "data").rglob("*.parquet")))
    return data.sort_values(["episode_index", "frame_index"])


def test_lerobot_record_stores_each_episodes_seed_and_outcome(recorded):
    root, _ = recorded
    data = frames(root)
    episodes = read_episodes(root)
    assert [(e.episode_index, e.seed) for e in episodes] == [(0, 0), (1, 1)]
    assert [e.length for e in episodes] == data.groupby("episode_index").size().tolist()
    assert all(e.success is False and e.first_success is None for e in episodes)  # the leader never grasps
    assert episodes[0].config["control_mode"] == "pd_joint_pos"
    assert episodes[0].config["rate_limited_steps"] == 8  # the 60-degree jump: 4 steps up, 4 back
    assert episodes[1].config["rate_limited_steps"] == 0


def test_lerobot_record_resets_at_its_boundaries_never_inside_an_episode(recorded, poses):
    root, _ = recorded
    data = frames(root)
    names = json.loads((root / "meta" / "info.json").read_text())["features"]["observation.state"]["names"]
    arm = [names.index(n) for n in ARM]
    for index, episode in data.groupby("episode_index"):
        state = np.stack(episode["observation.state"].to_numpy())
        largest = np.abs(np.diff(state[:, arm], axis=0)).max()
        assert largest <= SERVO_STEP * OVERSHOOT, f"episode {index}: a {largest:.1f} degree jump between frames"
        # each starts on its seed's start pose: the scene was reset at the boundary, on the episode's seed
        assert state[0] == pytest.approx(poses[index], abs=0.5)
    first = np.stack(data[data.episode_index == 0]["observation.state"].to_numpy())
    pan = first[:, names.index("shoulder_pan.pos")] - poses[0][0]
    assert np.abs(pan[:8]).max() < 0.5  # the arm waited at the start pose while the leader was off it
    assert pan.max() == pytest.approx(60.0, abs=1.0)  # then followed the leader's jump, within the servo's speed


def test_the_arm_waits_for_the_leader_and_says_which_joints_are_off(recorded):
    _, lines = recorded
    assert any(
        line.endswith("seed 0: the arm waits for the leader at its start pose (shoulder_pan.pos +25)") for line in lines
    )
    assert any(line.endswith("seed 0: the leader is at the start pose") for line in lines)
