"""LeRobot's own commands on the simulated SO-101 (`--robot.type=kitbench_so101`) as docs/teleoperation.md writes
them: the `lerobot-teleoperate`, `lerobot-record` and `lerobot-rollout` lines parsed from the docs and run through
each command's own `main()`, offline, with a scripted leader arm (`tests.lerobot_scripted`); the recording's episodes
reset at LeRobot's boundaries only, without a jump inside, each one's seed stored; the servos' speed limit on a
leader's jump; the start-pose wait; re-record."""

from __future__ import annotations

import contextlib
import json
import logging
import math
import re
import shlex
from collections.abc import Iterator
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


@contextlib.contextmanager
def plugin_lines() -> Iterator[list[str]]:
    """The plugin's INFO lines while the block runs (lerobot's own logging set-up, which shows them, is left out)."""
    plugin = logging.getLogger("lerobot_robot_kitbench")
    lines, level = Lines(), plugin.level
    plugin.addHandler(lines)
    plugin.setLevel(logging.INFO)
    try:
        yield lines.lines
    finally:
        plugin.removeHandler(lines)
        plugin.setLevel(level)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory, poses) -> tuple[Path, list[str]]:
    """The documented lerobot-record line, run for two episodes with a reset between; the leader starts 25 degrees
    off the start pose, comes to it, jumps 60 degrees in the pan and back, then rests at the start pose. A step limit
    of 30 (`--robot.episode_length`) falls while the arm is turned: a scene reset there would show."""
    where = tmp_path_factory.mktemp("record")
    start = poses[0]
    reads = [leader(start, 25.0)] * 10 + [leader(start)] * 20 + [leader(start, 60.0)] * 15 + [leader(start)]
    argv = replaced(doc_commands()["lerobot-record"], {**RECORD_OVERRIDES, "dataset.root": str(where / "sim")})
    with plugin_lines() as lines, pytest.MonkeyPatch.context() as patch:
        play([*argv, STATE_ONLY, "--robot.episode_length=30"], reads, patch)
    return where / "sim", lines


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
    assert [e.teleop["ended"] for e in episodes] == ["limit", "limit"]  # their time ran out
    assert episodes[0].teleop["rate_limited"] == 8  # the 60-degree jump: 4 steps up, 4 back
    assert episodes[1].teleop["rate_limited"] == 0
    assert [e.teleop["clipped"] for e in episodes] == [0, 0]


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


def test_a_leader_jump_reaches_the_follower_over_the_steps_the_servo_needs_counted():
    from lerobot.robots import RobotConfig, make_robot_from_config
    from lerobot.utils.import_utils import register_third_party_plugins

    register_third_party_plugins()
    config = RobotConfig.get_choice_class("kitbench_so101")(obs_mode="state", realtime=False)
    robot = make_robot_from_config(config)
    robot.connect()
    try:
        start = robot.get_observation()
        goal = dict(start) | {"shoulder_pan.pos": start["shoulder_pan.pos"] + 60.0}
        pans = [start["shoulder_pan.pos"]]
        for _ in range(8):
            assert robot.send_action(goal) == pytest.approx(goal)  # the goal is sent whole, not clipped
            pans.append(robot.get_observation()["shoulder_pan.pos"])
    finally:
        robot.disconnect()
    moved = np.array(pans) - pans[0]
    needed = math.ceil(60.0 / SERVO_STEP)  # 5 steps of 13.5 degrees
    assert np.diff(moved).max() <= SERVO_STEP * OVERSHOOT  # no faster than the servo
    assert moved[needed - 1] < 60.0 - 1.0 and moved[needed] == pytest.approx(60.0, abs=0.5)
    assert robot.limited_steps == needed - 1  # each step that ended short of the goal


def test_a_re_recorded_episode_meets_its_seed_again(tmp_path, poses, monkeypatch):
    """Left arrow during episode 0: LeRobot drops it, and records episode 0 again after its reset phase (which the
    right arrow cuts short), on seed 0 again; the right arrow ends that one early."""
    start = {**RECORD_OVERRIDES, "dataset.num_episodes": "1", "dataset.episode_time_s": "2"}
    argv = replaced(doc_commands()["lerobot-record"], {**start, "dataset.root": str(tmp_path / "sim")})
    with plugin_lines() as lines:
        play([*argv, STATE_ONLY], [leader(poses[0])], monkeypatch, keys={5: "left", 12: "right", 20: "right"})
    started = [line.split(": ", 1)[1] for line in lines if ": episode 0 on seed" in line]
    assert started == ["episode 0 on seed 0", "episode 0 on seed 0"]
    (kept,) = read_episodes(tmp_path / "sim")
    assert (kept.episode_index, kept.seed) == (0, 0)
    assert kept.teleop is not None and (kept.teleop["ended"], kept.teleop["key"]) == ("key", "right")
    assert len(frames(tmp_path / "sim")) == kept.length < 20  # the kept one's frames, fewer than its second


def test_the_documented_lerobot_teleoperate_line_runs(poses, monkeypatch):
    argv = replaced(doc_commands()["lerobot-teleoperate"], SCRIPTED)
    reads = play([*argv, STATE_ONLY, "--teleop_time_s=1"], [leader(poses[0], 10.0)], monkeypatch)
    assert reads >= 10  # a second of lerobot's loop at 20 fps read the leader each time


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> Path:
    """An untrained ACT of an SO-101 image recording's layout (its state, its two cameras, its six goals), saved as
    lerobot-train saves a `pretrained_model`: what lerobot-rollout loads, not a trained policy."""
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies import make_pre_post_processors
    from lerobot.policies.act.configuration_act import ACTConfig
    from lerobot.policies.act.modeling_act import ACTPolicy

    image = PolicyFeature(FeatureType.VISUAL, (3, 128, 128))
    config = ACTConfig(
        input_features={
            "observation.state": PolicyFeature(FeatureType.STATE, (6,)),
            "observation.images.front": image,
            "observation.images.wrist": image,
        },
        output_features={"action": PolicyFeature(FeatureType.ACTION, (6,))},
        chunk_size=5,
        n_action_steps=5,
        dim_model=64,
        dim_feedforward=128,
        n_encoder_layers=1,
        n_decoder_layers=1,
        pretrained_backbone_weights=None,
        device="cpu",
        push_to_hub=False,
    )
    vector = {"mean": np.zeros(6, np.float32), "std": np.full(6, 30.0, np.float32)}
    pixels = {"mean": np.full((3, 1, 1), 0.5, np.float32), "std": np.full((3, 1, 1), 0.25, np.float32)}
    stats = {"observation.state": vector, "action": vector}
    stats |= {"observation.images.front": pixels, "observation.images.wrist": pixels}
    folder = tmp_path_factory.mktemp("act") / "pretrained_model"
    ACTPolicy(config).save_pretrained(folder)
    for processor in make_pre_post_processors(config, dataset_stats=stats):
        processor.save_pretrained(folder)
    return folder


def test_the_documented_lerobot_rollout_line_runs(checkpoint, needs_vulkan, monkeypatch):
    argv = replaced(doc_commands()["lerobot-rollout"], {"policy.path": str(checkpoint), "duration": "2"})
    with plugin_lines() as lines:
        play(argv, [], monkeypatch)
    assert any("connected: AssemblingKits-v1, seed 0, 20 Hz" in line for line in lines)


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        ({"align": -1.0}, "align must be a number of degrees >= 0, got -1.0"),
        ({"viewer": True}, "viewer=true needs a display (DISPLAY is unset); without one, lerobot's own view can"),
    ],
)
def test_bad_plugin_settings_are_one_line(settings, message, monkeypatch):
    from lerobot.robots import RobotConfig
    from lerobot.utils.import_utils import register_third_party_plugins

    from kitbench.errors import KitbenchError

    register_third_party_plugins()
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(KitbenchError, match=re.escape(message)):
        RobotConfig.get_choice_class("kitbench_so101")(**settings)
