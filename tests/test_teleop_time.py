"""Time is the person's, and what is stored says how it was made: a teleoperated episode runs past the task's step
limit until the person ends it (a key, a gamepad's own button), at success, or at `max_seconds`; each stored
episode says how it ended with its clip and rate-limit counts; the settings keep the device's options and the
card's command records again with them; a device absent at the start is one line saying it was not found."""

from __future__ import annotations

import json
import shlex

import numpy as np
import pytest

import tests.teleop_devices as devices
from kitbench.registration import task_entry
from tests.teleop_devices import scripted_keys  # noqa: F401  (autouse: every test's scripted keys)
from tests.test_teleop_record import LIFT, episodes, error_line, expert, frames, record

SO101_LIMIT = task_entry(LIFT).env_class.episode_steps("so101")  # 100
FAST = ("--policy-option", "realtime=false")


@pytest.fixture(scope="module")
def start() -> dict:
    return expert(0).reads[0]  # the leader at the simulated arm's start pose


def test_a_persons_episode_runs_past_the_tasks_step_limit_until_the_person_ends_it(tmp_path, start):
    assert SO101_LIMIT == 100
    steps = SO101_LIMIT + 50
    jump = dict(start, **{"shoulder_pan.pos": start["shoulder_pan.pos"] - 60.0})  # a fast move, held back
    devices.SCRIPTS["default"] = devices.Script([start, *[jump] * steps], keys={steps: "right"})
    assert record(tmp_path, *FAST, "--policy-option", "id=my_leader") == 0
    (stored,) = episodes(tmp_path)
    assert stored["length"] == steps and not stored["success"]
    assert stored["teleop"] == {"ended": "key", "key": "right", "clipped": 0, "rate_limited": 4}
    assert not frames(tmp_path)["next.done"].iloc[: steps - 1].map(lambda v: bool(np.ravel(v)[0])).any()


def test_max_seconds_ends_an_episode_at_its_limit_and_says_so(tmp_path, start, capsys):
    devices.SCRIPTS["default"] = devices.Script([start])
    assert record(tmp_path, *FAST, "--policy-option", "max_seconds=7.5") == 0
    (stored,) = episodes(tmp_path)
    assert stored["length"] == 150 and stored["teleop"]["ended"] == "limit"  # 7.5 s at 20 Hz, past the task's 100
    assert "150 steps, ended at the 150-step limit (max_seconds)" in capsys.readouterr().err


def test_success_ends_it_after_the_settle_steps(tmp_path):
    truth = expert(0)
    devices.SCRIPTS["default"] = devices.Script(truth.reads)
    assert record(tmp_path, *FAST, "--settle-steps", "3") == 0
    (stored,) = episodes(tmp_path)
    assert stored["success"] and stored["length"] == len(truth.actions) + 3
    assert stored["teleop"]["ended"] == "success"


def test_settings_keep_the_devices_options_and_the_card_records_again_with_them(tmp_path, start):
    options = ("port=/dev/ttyACM7", "id=my_leader", "max_seconds=600")
    flags = [f for option in options for f in ("--policy-option", option)]
    devices.SCRIPTS["default"] = devices.Script([start], keys={3: "esc"})
    assert record(tmp_path, *FAST, *flags) == 0
    settings = json.loads((tmp_path / "out" / "meta" / "kitbench_recording.json").read_text())
    assert settings["teleop_options"] == {
        "realtime": False,
        "port": "/dev/ttyACM7",
        "id": "my_leader",
        "max_seconds": 600,
    }
    card = (tmp_path / "out" / "README.md").read_text()
    (line,) = [line for line in card.splitlines() if line.startswith("- Made again by:")]
    argv = shlex.split(line.split("`")[1])
    pairs = [argv[i + 1] for i, a in enumerate(argv) if a == "--policy-option"]
    assert pairs == ["realtime=false", "port=/dev/ttyACM7", "id=my_leader", "max_seconds=600"]
    assert argv[argv.index("--policy") + 1] == "teleop:kitbench_replay_arm"
    assert "scores the episodes under the task's own step limit (100 steps, 5 s)" in card
    assert "at most 600 s each (`max_seconds`)" in card


def test_secret_options_are_never_kept():
    from kitbench.metadata import teleop_options

    kept = teleop_options("teleop:phone", {"id": "a", "api_token": "x", "password": "y", "port": 3})
    assert kept == {"id": "a", "port": 3}
    assert teleop_options("expert", {"id": "a"}) is None


def test_a_gamepads_own_buttons_re_record_end_and_stop(tmp_path, capsys):
    still = {"delta_x": 0.0, "delta_y": 0.0, "delta_z": 0.0, "gripper": 1.0}
    # seed 0: X at its 5th read (re-record), Y at the 6th of its second try (end, kept); seed 1: A at its 7th (stop)
    events = {4: "RERECORD_EPISODE", 5 + 5: "SUCCESS", 5 + 6 + 6: "TERMINATE_EPISODE"}
    devices.SCRIPTS["default"] = devices.Script([still], events=events)
    assert record(tmp_path, device="kitbench_replay_gamepad", robot="panda", mode="pd_ee_delta_pos", episodes=3) == 0
    err = capsys.readouterr().err
    assert "teleop: seed 0: no success, 5 steps, discarded (re-record)" in err
    stored = episodes(tmp_path)
    assert [(e["seed"], e["length"], e["teleop"]["ended"], e["teleop"].get("button")) for e in stored] == [
        (0, 6, "button", "success"),
        (1, 7, "button", "terminate_episode"),
    ]
    assert "stopped as asked (escape)" in err


def test_a_device_absent_at_the_start_is_one_line_saying_it_was_not_found(tmp_path, capsys):
    devices.SCRIPTS["default"] = devices.Script([{}], fail_at=0)
    assert record(tmp_path, device="kitbench_replay_gamepad", robot="panda", mode="pd_ee_delta_pos") == 2
    line = error_line(capsys.readouterr().err)
    assert line == (
        "kitbench record: error: teleop:kitbench_replay_gamepad: not found: OSError: device reports readiness to "
        "read but returned no data (device disconnected?)"
    )
    assert "--resume" not in line and " disconnected while" not in line
