"""`kitbench record --policy teleop:<device>` with scripted LeRobot teleoperators (registered through lerobot's
`TeleoperatorConfig` registry, built by lerobot's factory, as a real device is; `tests/teleop_devices`): a leader
arm replaying the expert's joint stream reproduces its episode, a phone replaying its TCP path does too, gamepad
deltas land as end-effector actions; a missing or unplugged device is one line and `--resume` continues; lerobot-
record's keys (fed through the listener's own dispatch) re-record, end and stop episodes. Episodes run in real time
(20 Hz), a few seconds each."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass

import numpy as np
import pandas as pd
import pytest

import tests.teleop_devices as devices
from kitbench.cli import main as kitbench
from kitbench.envs.features import STATE, observation_frame
from kitbench.policies.registry import make_policy
from kitbench.registration import make_env
from kitbench.rollout import Hook, OneEpisode, run
from kitbench.teleop.mapping import commanded_tcp
from tests.teleop_devices import scripted_keys  # noqa: F401  (autouse: every test's scripted keys)

LIFT = "LiftPegUpright-v1"
NAMES = [f"{m}.pos" for m in devices.SO101_MOTORS]


@dataclass
class Expert:
    """One expert episode: where the arm started, what it executed, and the TCP it was measured at each step."""

    start: np.ndarray  # observation.state at reset, the robot's units
    actions: list[np.ndarray]
    measured: list[np.ndarray]  # 4x4 base-frame TCP before each step
    reference: np.ndarray  # the TCP commanded at reset
    success: bool

    @property
    def reads(self) -> list[dict]:
        """A leader arm held at the start pose, then following the expert's joint targets."""
        return [dict(zip(NAMES, map(float, self.start), strict=True))] + [
            dict(zip(NAMES, map(float, a), strict=True)) for a in self.actions
        ]


class Capture(Hook):
    def __init__(self) -> None:
        self.expert: Expert | None = None

    def on_reset(self, episode) -> None:
        start = observation_frame(episode.env, episode.obs)[STATE]
        self.expert = Expert(start, [], [], commanded_tcp(episode.env), False)

    def on_action(self, episode, action, executed) -> None:
        env = episode.env
        assert self.expert is not None
        self.expert.actions.append(executed.copy())
        self.expert.measured.append(env.controller.kinematics.tcp_pose(env.robot.arm_qpos()))

    def on_end(self, episode) -> None:
        assert self.expert is not None
        self.expert.success = episode.success


def expert(seed: int, robot: str = "so101", mode: str = "pd_joint_pos") -> Expert:
    env = make_env(LIFT, obs_mode="state", control_mode=mode, robot_uids=robot)
    capture = Capture()
    try:
        run([env], [seed], OneEpisode(make_policy("expert")), lambda _: [capture])
    finally:
        env.close()
    assert capture.expert is not None
    return capture.expert


@pytest.fixture(scope="module")
def experts() -> dict[int, Expert]:
    return {seed: expert(seed) for seed in (0, 1, 2)}


def record(tmp_path, *flags: str, device: str = "kitbench_replay_arm", robot: str = "so101", seed: int = 0,
           episodes: int = 1, mode: str = "pd_joint_pos") -> int:  # fmt: skip
    # fmt: off
    argv = ["record", "--task", LIFT, "--robot", robot, "--control-mode", mode, "--seed", str(seed),
            "--episodes", str(episodes), "--out", str(tmp_path / "out"), "--policy", f"teleop:{device}", *flags]
    # fmt: on
    return kitbench(argv)


def frames(tmp_path) -> pd.DataFrame:
    files = sorted((tmp_path / "out" / "data").rglob("*.parquet"))
    return pd.concat([pd.read_parquet(f) for f in files]).sort_values(["episode_index", "frame_index"])


def episodes(tmp_path) -> list[dict]:
    lines = (tmp_path / "out" / "meta" / "kitbench_episodes.jsonl").read_text().splitlines()
    return [json.loads(line) for line in lines]


def error_line(err: str) -> str:
    (line,) = [line for line in err.splitlines() if line.startswith("kitbench record: error:")]
    return line


def test_a_leader_arm_replaying_the_experts_joint_stream_reproduces_its_episode_in_real_time(tmp_path, experts, capsys):
    truth = experts[0]
    assert truth.success
    devices.SCRIPTS["default"] = devices.Script(truth.reads)
    started = time.perf_counter()
    assert record(tmp_path) == 0
    elapsed = time.perf_counter() - started
    data = frames(tmp_path)
    np.testing.assert_allclose(np.stack(data["action"].to_numpy()), np.stack(truth.actions), atol=1e-3)
    (stored,) = episodes(tmp_path)
    assert stored["success"] and stored["length"] == len(truth.actions)
    # paced at the task's 20 Hz on the wall clock, not as fast as the simulation goes (~1 ms a state step)
    assert elapsed >= 0.9 * len(truth.actions) * 0.05
    settings = json.loads((tmp_path / "out" / "meta" / "kitbench_recording.json").read_text())
    assert settings["policy"] == "teleop:kitbench_replay_arm"
    card = (tmp_path / "out" / "README.md").read_text()
    assert "a person at the controls, with LeRobot's `kitbench_replay_arm` teleoperator" in card
    assert (tmp_path / "out" / "mcap" / "episode_000000.mcap").is_file()
    err = capsys.readouterr().err
    assert f"teleop: seed 0: success at step {len(truth.actions)}, {len(truth.actions)} steps" in err
    assert "no value beyond the simulated joint limits" in err and "paced steps at 20 Hz" in err


def test_a_phone_replaying_the_experts_tcp_path_reproduces_its_success_on_the_panda(tmp_path):
    from lerobot.utils.rotation import Rotation

    from kitbench.control.controllers import make_controller
    from kitbench.geometry import axis_angle_to_matrix, matrix_to_axis_angle

    truth = expert(1, robot="panda", mode="pd_ee_delta_pose")
    assert truth.success
    decode = make_controller("pd_ee_delta_pose", np.zeros((7, 2)), lambda: None).decode  # ManiSkill's form to SI
    reads, jaw = [], 100.0
    for action, measured in zip(truth.actions, truth.measured, strict=True):
        delta = decode(action[:6])
        target = np.eye(4)  # where the expert's delta took the TCP from where it was measured
        target[:3, 3] = measured[:3, 3] + delta[:3]
        target[:3, :3] = axis_angle_to_matrix(delta[3:6]) @ measured[:3, :3]
        move = target[:3, 3] - truth.reference[:3, 3]  # the phone's pose since its press, lerobot's phone axes
        turn = matrix_to_axis_angle(truth.reference[:3, :3].T @ target[:3, :3])
        percent = 50.0 * (1.0 + float(action[-1]))
        reads.append(
            {
                "phone.pos": np.array([move[1], -move[0], move[2]]),
                "phone.rot": Rotation.from_rotvec(np.array([turn[1], turn[0], -turn[2]])),
                "phone.raw_inputs": {"a3": (percent - jaw) / 20.0},
                "phone.enabled": True,
            }
        )
        jaw = percent
    devices.SCRIPTS["default"] = devices.Script(reads)
    assert record(tmp_path, device="kitbench_replay_phone", robot="panda", seed=1, mode="pd_ee_delta_pose") == 0
    (stored,) = episodes(tmp_path)
    assert stored["success"]
    data = np.stack(frames(tmp_path)["action"].to_numpy())
    np.testing.assert_allclose(data[:10], np.stack(truth.actions[:10]), atol=1e-4)


def test_gamepad_deltas_are_stored_as_end_effector_actions_at_the_set_speed(tmp_path):
    steps = 50  # the person ends it with the right arrow
    k = np.arange(steps)
    deltas = np.stack([np.sin(k / 5), 0.5 * np.cos(k / 7), np.where(k < 25, -0.4, 0.4)], axis=1)
    classes = np.where(k < 10, 2.0, np.where(k < 12, 0.0, 1.0))  # open, then close, then stay
    reads = [
        dict(zip(("delta_x", "delta_y", "delta_z", "gripper"), [*d, c], strict=True))
        for d, c in zip(deltas, classes, strict=True)
    ]
    devices.SCRIPTS["default"] = devices.Script(reads, keys={steps - 1: "right"})
    assert record(tmp_path, device="kitbench_replay_gamepad", robot="panda", mode="pd_ee_delta_pos") == 0
    data = np.stack(frames(tmp_path)["action"].to_numpy())
    assert data.shape == (steps, 4)
    # 0.1 m/s at full deflection, 20 Hz, in ManiSkill's normalised deltas (1 is 0.1 m)
    np.testing.assert_allclose(data[:, :3], deltas * 0.1 * 0.05 / 0.1, atol=1e-6)
    np.testing.assert_array_equal(data[:, 3], np.where(k < 10, 1.0, -1.0))


def test_a_missing_device_is_one_line_naming_it_and_its_port_and_nothing_is_written(tmp_path, capsys):
    devices.SCRIPTS["default"] = devices.Script([{}], missing=True)
    assert record(tmp_path) == 2
    assert error_line(capsys.readouterr().err) == (
        "kitbench record: error: teleop:kitbench_replay_arm on /dev/kitbench-replay: cannot connect: "
        "ConnectionError: Could not connect on port '/dev/kitbench-replay'"
    )
    assert not any(tmp_path.iterdir())


def test_an_unplugged_device_keeps_the_finished_episodes_and_resume_continues(tmp_path, experts, capsys):
    first, second, third = experts[0].reads, experts[1].reads, experts[2].reads
    devices.SCRIPTS["default"] = devices.Script(first + second[:6], fail_at=len(first) + 6)
    assert record(tmp_path, episodes=3) == 2
    line = error_line(capsys.readouterr().err)
    assert line.startswith(
        "kitbench record: error: teleop:kitbench_replay_arm on /dev/kitbench-replay disconnected while recording "
        "seed 1: OSError: device reports readiness to read but returned no data"
    )
    assert line.endswith("the episode in flight is discarded and every finished one kept: continue with --resume")
    devices.SCRIPTS["default"] = devices.Script(second + third)  # plugged in again, the person goes on
    assert record(tmp_path, "--resume", episodes=3) == 0
    stored = episodes(tmp_path)
    assert [e["seed"] for e in stored] == [0, 1, 2] and all(e["success"] for e in stored)
    assert [e["length"] for e in stored] == [len(experts[s].actions) for s in (0, 1, 2)]  # seed 1 whole, once


def test_re_record_next_and_stop_keys_do_what_lerobot_records_do(tmp_path, experts, capsys):
    zero, one, two = experts[0].reads, experts[1].reads, experts[2].reads
    # seed 0: left arrow at step 10 (re-record), then the whole episode; seed 1: escape at step 8 (stop)
    reads = zero[:11] + zero + one[:9]
    keys = {10: "left", len(zero) + 11 + 8: "esc"}
    devices.SCRIPTS["default"] = devices.Script(reads, keys=keys)
    assert record(tmp_path, episodes=3) == 0
    err = capsys.readouterr().err
    assert "teleop: seed 0: no success, 10 steps, discarded (re-record)" in err
    assert "teleop: seed 1: no success, 8 steps, stopped" in err
    assert "stopped as asked (escape): the episodes stored are committed; continue with --resume" in err
    stored = episodes(tmp_path)
    # the re-recorded seed ran again from its start; the stopped episode is kept as lerobot-record keeps it
    assert [(e["seed"], e["length"], e["success"]) for e in stored] == [
        (0, len(experts[0].actions), True),
        (1, 8, False),
    ]
    # seed 2: right arrow at step 5 ends it early and the recording, now complete, ends
    devices.SCRIPTS["default"] = devices.Script(two, keys={5: "right"})
    assert record(tmp_path, "--resume", episodes=3) == 0
    assert [(e["seed"], e["length"]) for e in episodes(tmp_path)][-1] == (2, 5)
    assert "teleop: seed 2: no success, 5 steps, ended early (next)" in capsys.readouterr().err


def test_escape_while_bringing_the_leader_to_the_start_pose_stops_before_the_episode(tmp_path, experts, capsys):
    away = dict(experts[0].reads[0])
    away["elbow_flex.pos"] += 30.0  # the leader far from the simulated arm's start
    devices.SCRIPTS["default"] = devices.Script([away, away, away], keys={2: "q"})
    assert record(tmp_path, episodes=2) == 0
    err = capsys.readouterr().err
    assert "bring the leader to the simulated arm's start pose (elbow_flex.pos +30)" in err
    assert "stopped as asked (escape)" in err
    assert not (tmp_path / "out" / "meta" / "kitbench_episodes.jsonl").exists() or episodes(tmp_path) == []


def test_more_workers_are_refused_in_one_line_before_anything_is_written(tmp_path, capsys):
    devices.SCRIPTS["default"] = devices.Script([{}])
    assert record(tmp_path, "--workers", "2") == 2
    assert error_line(capsys.readouterr().err) == (
        "kitbench record: error: policy teleop:kitbench_replay_arm drives one episode at a time: record with "
        "--workers 1 (got 2)"
    )
    assert not any(tmp_path.iterdir())
