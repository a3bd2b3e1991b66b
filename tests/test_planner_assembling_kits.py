"""The AssemblingKits-v1 expert: real insertions on a fixed seed set, and its wrist/yaw choice."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

import kitbench  # noqa: F401
from kitbench.geometry import planar_yaw, quat_to_matrix
from kitbench.planning.assembling_kits import AssemblingKitsPlanner, signed_yaw_options
from kitbench.tasks.assembling_kits import yaw_error

# seed: shape — a disc lying on the table next to the board, a hexagon (2 pi / 6), a rectangle (pi), a kite
# (asymmetric), a square on the board (pi / 2)
SEEDS = {0: 11, 1: 17, 24: 6, 6: 15, 28: 3}


def _run(env, seed):
    obs, info = env.reset(seed=seed)
    planner = AssemblingKitsPlanner(env)
    steps = 0
    while True:
        obs, _, terminated, truncated, info = env.step(planner.act(obs))
        steps += 1
        if terminated or truncated:
            return info, steps, planner


@pytest.fixture(scope="module")
def env():
    e = gym.make("kitbench/AssemblingKits-v1", control_mode="pd_joint_pos")
    yield e
    e.close()


@pytest.mark.parametrize("seed", sorted(SEEDS))
def test_expert_inserts_the_shape(env, seed):
    info, steps, planner = _run(env, seed)
    assert env.unwrapped.shape.shape_id == SEEDS[seed]
    assert info["success"], (info, planner.phase, planner.failure)
    assert steps <= 120  # well inside the 200-step budget


def test_expert_in_joint_delta_mode():
    env = gym.make("kitbench/AssemblingKits-v1", control_mode="pd_joint_delta_pos")
    from kitbench.policies.expert import ExpertPolicy

    policy = ExpertPolicy()
    obs, info = env.reset(seed=1)
    policy.reset(env, 1, obs, info)
    for _ in range(200):
        obs, _, terminated, truncated, info = env.step(policy.act(obs))
        if terminated or truncated:
            break
    assert info["success"]


@pytest.mark.parametrize(
    "delta,symmetry,expected",
    [
        (0.3, 2 * math.pi, [0.3 - 2 * math.pi, 0.3]),
        (0.3, math.pi / 2, [0.3 + k * math.pi / 2 for k in range(-4, 4)]),
        (1.0, 0.0, [0.0]),
    ],
)
def test_yaw_options_are_the_goal_yaws_equivalent_under_symmetry(delta, symmetry, expected):
    options = signed_yaw_options(delta, symmetry)
    np.testing.assert_allclose(sorted(options), sorted(expected), atol=1e-12)
    assert all(abs(o) <= 2 * math.pi + 1e-9 for o in options)


@pytest.mark.parametrize("seed", [24, 28, 6])
def test_chosen_turn_reaches_an_equivalent_goal_yaw_within_joint7_limits(env, seed):
    env.reset(seed=seed)
    u = env.unwrapped
    planner = AssemblingKitsPlanner(env)
    start = planner._last()
    turn, rotation = planner._choose_grasp(start)
    obj_yaw = planar_yaw(quat_to_matrix(u.obj.pose.q))
    assert yaw_error(obj_yaw + rotation, u.goal_rot, u.shape.symmetry) < 1e-9
    q7_grasp = start.q[6] - turn
    lo, hi = planner.q7_limits
    assert lo < q7_grasp < hi and lo < q7_grasp - rotation < hi
    if u.shape.symmetry > 0:  # never more rotation than the symmetry makes necessary, plus a half turn at most
        assert abs(rotation) <= u.shape.symmetry / 2 + math.pi + 1e-9
