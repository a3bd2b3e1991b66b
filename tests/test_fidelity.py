"""Fidelity to ManiSkill 3.0.1: its actions mean the same here, and its own demonstrations succeed replayed here.

The fixtures were made in ManiSkill by `bench/fidelity.py --fixture-dir tests/data`: episodes of its LiftPegUpright
motion-planning solution (its start, its `pd_joint_pos` actions and the peg's pose after every step), and each
control mode's answer to fixed actions (the TCP and the controller's TCP target after every step), so CI holds
fidelity without ManiSkill installed.
"""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import kitbench  # noqa: F401  (registers the tasks)
from bench.fidelity import FIXTURE_EPISODES, FIXTURE_MODES, load_episodes, replay_in_kitbench, replay_mode, tilt_deg
from kitbench.control.controllers import CONTROL_MODES, make_controller
from kitbench.errors import KitbenchError
from kitbench.planning.phases import CLOSED, OPEN
from kitbench.policies.joint_targets import joint_target_to_action
from kitbench.teleop.mapping import jaw_command

DATA = Path(__file__).parent / "data"
EPISODES = load_episodes(DATA / FIXTURE_EPISODES)
MODES = np.load(DATA / FIXTURE_MODES)


@pytest.fixture(scope="module")
def lift_env():
    env = gym.make("kitbench/LiftPegUpright-v1", obs_mode="state", control_mode="pd_joint_pos").unwrapped
    yield env
    env.close()


@pytest.mark.parametrize("index", range(len(EPISODES)), ids=[f"seed{e['seed']}" for e in EPISODES])
def test_maniskill_solution_succeeds_replayed(lift_env, index):
    """ManiSkill's own solution, open loop from ManiSkill's start: it stands the peg as it did there, the peg's
    tilt and height along the way within a few degrees and millimetres of ManiSkill's."""
    episode = EPISODES[index]
    assert episode["success"]
    replayed = replay_in_kitbench(lift_env, episode["seed"], episode["qpos0"], episode["peg0"], episode["actions"])
    assert replayed["success"]
    ours, theirs = replayed["peg"], episode["peg"]
    assert abs(tilt_deg(ours[-1]) - tilt_deg(theirs[-1])) < 2.0
    assert abs(ours[-1][2] - theirs[-1][2]) < 0.002
    along = [abs(tilt_deg(a) - tilt_deg(b)) for a, b in zip(ours, theirs, strict=True)]
    assert max(along) < 5.0, f"the peg's tilt left ManiSkill's by {max(along):.1f} degrees on the way"


def _opening_after(env, command: float, steps: int = 15) -> float:
    for _ in range(steps):
        env.step(joint_target_to_action(env, env.robot.arm_qpos(), command))
    return env.robot.gripper_opening()


@pytest.mark.parametrize("robot", ["panda", "panda_wristcam", "fetch", "so101"])
def test_gripper_plus_one_opens_in_every_mode(robot):
    """+1 opens and -1 closes, as in ManiSkill (its Panda: fingers at 0.04 after 15 steps of +1, 0 after -1)."""
    task = "kitbench/AssemblingKits-v1" if robot == "panda_wristcam" else "kitbench/LiftPegUpright-v1"
    for mode in CONTROL_MODES:
        env = gym.make(task, robot_uids=robot, obs_mode="state", control_mode=mode).unwrapped
        env.reset(seed=0)
        spec = env.robot_spec
        n = len(spec.finger_joints)
        closed = _opening_after(env, CLOSED)
        opened = _opening_after(env, OPEN)
        assert opened == pytest.approx(n * spec.finger_open, abs=0.005), (robot, mode)
        span = spec.finger_open - spec.finger_closed
        assert closed < n * (spec.finger_closed + 0.25 * span), (robot, mode)  # at the closed end of its range
        env.close()


def test_gripper_convention_through_expert_and_teleop(lift_env):
    """The expert approaches with the hand open (+1) and grasps with it closed (-1); a leader's jaw at 100% opens."""
    obs, info = lift_env.reset(seed=3)
    expert = lift_env.make_expert()
    expert.reset(obs, info, seed=3)
    commands = []
    for _ in range(20):
        action = expert.act(obs)
        commands.append((expert.phase, float(action[-1])))
        obs, *_ = lift_env.step(action)
    assert {c for p, c in commands if p == "approach"} == {1.0}
    assert {c for p, c in commands if p == "grasp"} == {-1.0}
    assert jaw_command(100.0) == 1.0 and jaw_command(0.0) == -1.0


@pytest.mark.parametrize(
    "options,name", [({"arm_qpos": [0.0, 1.0]}, "arm_qpos"), ({"peg_pose": [0.0, 0.0, float("nan")] * 3}, "peg_pose")]
)
def test_bad_initial_state_is_one_line(lift_env, options, name):
    with pytest.raises(KitbenchError, match=name) as caught:
        lift_env.reset(seed=0, options=options)
    assert "\n" not in str(caught.value)
    np.testing.assert_equal(lift_env.reset(seed=0)[0], lift_env.reset(seed=0)[0])


@pytest.mark.parametrize("mode", CONTROL_MODES)
def test_an_action_means_what_it_means_in_maniskill(mode):
    """The same action from the same start: an end-effector mode's first TCP target is ManiSkill's to a micrometre
    (normalisation, frames, the Euler rotation and its sign); the joint modes and `pd_ee_pose` move the TCP as
    ManiSkill's do, step by step. (Later targets of the end-effector delta modes part: ManiSkill's CPU IK holds
    the arm on steps it does not converge on, and it bounds no target's lead: docs/fidelity.md.)"""
    rows = replay_mode(MODES, mode)
    if "_ee_" in mode:
        assert rows[0]["target_mm"] < 1e-3 and rows[0]["target_deg"] < 1e-3, rows[0]
    if "_ee_" not in mode or mode == "pd_ee_pose":
        assert max(r["tcp_mm"] for r in rows) < 2.0 and max(r["tcp_deg"] for r in rows) < 0.5
    if mode == "pd_ee_pose":
        assert max(r["target_mm"] for r in rows) < 1e-3 and max(r["target_deg"] for r in rows) < 1e-3


@pytest.mark.parametrize("mode", CONTROL_MODES)
def test_decode_and_encode_are_inverse(mode):
    """The action box is ManiSkill's ([-1, 1] for a delta mode), and an action read into physical units and back
    is itself (rotations within the box's norm-1 ball; absolute Euler angles where they are unique, the middle one
    within +-pi/2)."""
    controller = make_controller(mode, np.array([[-2.9, 2.9]] * 7), lambda: None)
    space = controller.action_space
    if mode != "pd_joint_pos" and mode != "pd_ee_pose":
        assert np.all(space.low == -1.0) and np.all(space.high == 1.0)
    rng = np.random.default_rng(0)
    for _ in range(20):
        action = rng.uniform(space.low[:-1], space.high[:-1]) * (0.2 if mode == "pd_ee_pose" else 0.5)
        np.testing.assert_allclose(controller.encode(controller.decode(action)), action, atol=1e-9)
    if controller.delta:
        np.testing.assert_allclose(controller.decode(np.ones(space.shape[0] - 1))[:3], 0.1)
