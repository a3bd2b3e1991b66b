"""Fidelity to ManiSkill 3.0.1: its actions mean the same here, and its own demonstrations succeed replayed here.

The fixture holds episodes of ManiSkill's LiftPegUpright motion-planning solution made in ManiSkill by
`bench/fidelity.py --fixture` (its start, its `pd_joint_pos` actions and the peg's pose after every step), so CI
holds fidelity without ManiSkill installed.
"""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import kitbench  # noqa: F401  (registers the tasks)
from bench.fidelity import load_episodes, replay_in_kitbench, tilt_deg
from kitbench.control.controllers import CONTROL_MODES
from kitbench.errors import KitbenchError
from kitbench.planning.phases import CLOSED, OPEN
from kitbench.policies.joint_targets import joint_target_to_action
from kitbench.teleop.mapping import jaw_command

FIXTURE = Path(__file__).parent / "data/maniskill_lift_peg_upright.npz"
EPISODES = load_episodes(FIXTURE)


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
