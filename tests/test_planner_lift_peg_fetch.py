"""Fetch's LiftPegUpright-v1 expert: stands the peg upright across the peg's x range in `pd_joint_pos` and
`pd_joint_delta_pos`, deterministically, and the peg stays put in the hand through the swing.

The expert needs more than the task's 50 control steps (its module docstring: Fetch's wrist turns by ~2 rad
twice within the real arm's limits); Fetch episodes run the task's 170 steps for Fetch, and each test checks the
steps it took against the measured figures."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import kitbench  # noqa: F401  (registers the tasks)
from kitbench.planning.lift_peg_upright_fetch import FetchLiftPegUprightPlanner
from kitbench.planning.poses import pose_matrix, rotation_angle
from kitbench.policies.joint_targets import joint_target_to_action

# Seeds whose peg centres spread over x in [-0.1, 0.1] (x0: -0.091 .. 0.084).
SEEDS = (0, 1, 2, 3, 5, 8, 9, 13)
# Measured over seeds 0-499: max 138 steps in pd_joint_pos; over seeds 0-99 under ManiSkill's drives, whose 0.1 rad
# leads the joint-delta plans may use less of (planning/planner.py), max 161 in pd_joint_delta_pos.
MAX_STEPS = {"pd_joint_pos": 140, "pd_joint_delta_pos": 165}


def _env(control_mode: str):
    return gym.make(
        "kitbench/LiftPegUpright-v1",
        robot_uids="fetch",
        control_mode=control_mode,
        obs_mode="state_dict",
        max_episode_steps=MAX_STEPS[control_mode],
    )


def run(env, planner, seed: int, on_step=None):
    """Play one episode; returns (info, actions, phases). `on_step(phase)` runs after each step."""
    obs, info = env.reset(seed=seed)
    planner.reset(obs, info)
    actions, phases = [], []
    terminated = truncated = False
    while not (terminated or truncated):
        target = planner.act(obs)
        action = joint_target_to_action(env, target[:-1], float(target[-1]))
        actions.append(action)
        phases.append(planner.phase)
        obs, _, terminated, truncated, info = env.step(action)
        if on_step is not None:
            on_step(planner.phase)
    return info, np.array(actions), phases


def test_the_task_names_the_fetch_expert():
    env = _env("pd_joint_pos")
    assert isinstance(env.unwrapped.make_expert(), FetchLiftPegUprightPlanner)


@pytest.mark.parametrize("control_mode", ["pd_joint_pos", "pd_joint_delta_pos"])
def test_expert_stands_the_peg_upright(control_mode):
    env = _env(control_mode)
    planner = FetchLiftPegUprightPlanner(env)
    for seed in SEEDS:
        info, actions, phases = run(env, planner, seed)
        assert info["success"], (control_mode, seed, planner.failure, phases[-1], info["tilt"], info["z_error"])
        assert planner.failure is None and planner.grasp_attempts == 1
        # body and base entries stay zero: the torso and the base hold still
        assert np.all(actions[:, 8:] == 0.0)


def test_episodes_are_deterministic():
    env = _env("pd_joint_pos")
    planner = FetchLiftPegUprightPlanner(env)
    first = run(env, planner, SEEDS[2])
    second = run(env, planner, SEEDS[2])
    np.testing.assert_array_equal(first[1], second[1])
    assert first[0]["success"] and first[2] == second[2]


def test_the_peg_stays_put_in_the_hand_during_the_swing():
    """The peg hangs from its end on a 0.09 m lever. Measured over the swing, relative to the TCP: at most 3.2 mm
    and 1.7 degrees on these seeds, 5.9 mm / 3.4 degrees on the worst of 13 checked (seed 34, still upright:
    tilt 0.075 of 0.08); a grasp 5 mm shallower let it turn 6.5 degrees and drag on the table."""
    env = _env("pd_joint_pos")
    planner = FetchLiftPegUprightPlanner(env)
    u = env.unwrapped
    relative: list[np.ndarray] = []

    def record(phase):
        if phase == "swing":
            relative.append(np.linalg.inv(pose_matrix(u.robot.tcp_pose())) @ pose_matrix(u.peg.pose))

    for seed in SEEDS:
        relative.clear()
        info, _, _ = run(env, planner, seed, on_step=record)
        assert info["success"] and len(relative) > 20
        shift = max(float(np.linalg.norm(r[:3, 3] - relative[0][:3, 3])) for r in relative)
        turn = max(rotation_angle(r[:3, :3], relative[0][:3, :3]) for r in relative)
        assert shift < 0.005, (seed, shift)
        assert np.degrees(turn) < 3.0, (seed, np.degrees(turn))
