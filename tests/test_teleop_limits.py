"""The follower's joint speeds hold for a person: a leader's jump is rate-limited as the real servo follows it (never
clipped in position), over the steps the servo needs, and those steps are counted."""

from __future__ import annotations

import math

import numpy as np
import pytest

import tests.teleop_devices as devices
from kitbench.errors import KitbenchError
from kitbench.robots import ROBOTS
from kitbench.teleop.limits import JointRateLimiter
from tests.teleop_devices import scripted_keys  # noqa: F401  (autouse: every test's scripted keys)
from tests.test_teleop_record import expert, frames, record

SIXTY = math.radians(60.0)
DT = 0.05


@pytest.mark.parametrize(
    "robot, speeds",
    [
        ("so101", (4.7,) * 5),
        ("panda", (2.175,) * 4 + (2.61,) * 3),
        ("fetch", (1.256, 1.454, 1.571, 1.521, 1.571, 2.268, 2.268)),
    ],
)
def test_each_robot_declares_its_real_joint_speeds(robot, speeds):
    limiter = JointRateLimiter.for_robot(ROBOTS[robot], DT)
    np.testing.assert_allclose(limiter.max_speed, speeds)


def test_a_60_degree_jump_is_reached_over_the_steps_the_servo_needs_never_clipped():
    limiter = JointRateLimiter.for_robot(ROBOTS["so101"], DT)
    start = np.zeros(5)
    limiter.reset(start)
    target = start.copy()
    target[0] = SIXTY
    need = math.ceil(SIXTY / (4.7 * DT))  # 13.5 degrees a step: 5 steps
    assert need == limiter.steps_to_reach(start, target) == 5
    commanded = [limiter(target) for _ in range(need + 2)]
    pans = [c[0][0] for c in commanded]
    assert [c[1] for c in commanded] == [True] * (need - 1) + [False] * 3  # the last step fits in one period
    np.testing.assert_allclose(np.diff([0.0, *pans])[: need - 1], 4.7 * DT)
    assert pans[need - 1] == pytest.approx(SIXTY) and pans[-1] == pytest.approx(SIXTY)
    assert limiter.limited_steps == need - 1
    np.testing.assert_array_equal([c[0][1:] for c in commanded], np.zeros((need + 2, 4)))  # the others stay
    limiter.reset(start)  # a new episode counts afresh
    assert limiter.limited_steps == 0


def test_bad_speeds_and_targets_before_reset_are_refused():
    with pytest.raises(KitbenchError, match="joint speed limits must be positive"):
        JointRateLimiter(np.array([1.0, 0.0]), DT)
    limiter = JointRateLimiter(np.ones(2), DT)
    with pytest.raises(KitbenchError, match="reset to 3 values"):
        limiter.reset(np.zeros(3))
    with pytest.raises(RuntimeError):
        limiter(np.zeros(2))


def test_a_leaders_60_degree_jump_reaches_the_simulated_follower_over_the_servos_steps_counted(tmp_path, capsys):
    start = expert(0).reads[0]  # the leader at the simulated arm's start pose
    jumped = dict(start)
    jumped["shoulder_pan.pos"] += 60.0
    steps = 14
    devices.SCRIPTS["default"] = devices.Script([start, *[jumped] * steps], keys={steps: "right"})
    assert record(tmp_path, "--policy-option", "realtime=false") == 0
    data = frames(tmp_path)
    pan_action = np.stack(data["action"].to_numpy())[:, 0]
    pan_state = np.stack(data["observation.state"].to_numpy())[:, 0]
    per_step = math.degrees(4.7 * DT)  # 13.47 degrees
    goal = start["shoulder_pan.pos"] + 60.0
    # the start pose is read while waiting for the leader; from the first step the pan moves at the servo's speed
    # and reaches the leader on the 5th
    np.testing.assert_allclose(np.diff([start["shoulder_pan.pos"], *pan_action[:4]]), per_step, rtol=1e-4)
    assert np.all(np.abs(pan_action[4:] - goal) < 1e-3)
    # the simulated follower is at the leader's pose within a degree two periods later
    assert abs(pan_state[6] - goal) < 1.0
    # no frame moved the follower faster than its servo
    assert np.max(np.abs(np.diff(pan_state))) <= per_step + 0.5
    assert "4 steps held to the follower's joint speeds" in capsys.readouterr().err
