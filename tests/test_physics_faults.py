"""A diverged simulation ends the episode cleanly: truncated, reward 0, finite observations, `info["physics_error"]`.

The fault: the AssemblingKits ring (kit 156, the kit `reset(seed=112)` draws) given a NaN velocity, which PhysX
integrates into a NaN pose within one control step. It stands in for a real one that is gone: released 1 cm above
its seated pose and 1 degree off in yaw, that ring used to come out of PhysX with a NaN pose, until the kit board
collided as one triangle mesh (docs/kit-physics.md).
"""

from __future__ import annotations

import json
import math

import gymnasium as gym
import numpy as np
import pytest
import sapien
from sapien import physx

import kitbench  # noqa: F401
from kitbench.envs.grasp import GraspHistory
from kitbench.envs.physics_watch import MAX_BODY_SPEED
from kitbench.evaluation.episode import evaluate_episode
from kitbench.evaluation.outcomes import PHYSICS_ERROR, failure_category
from kitbench.evaluation.report import build_report
from kitbench.evaluation.suite import adhoc_suite
from kitbench.geometry import yaw_quat

HOLD = np.array([0, 0, 0, 0, 0, 0, 0, -1], dtype=np.float32)
RING_SEED = 112


def _explode_ring(u) -> None:
    """Put the ring where it used to explode, moving at a NaN velocity (see the module docstring)."""
    pose = sapien.Pose([u.goal_pos[0], u.goal_pos[1], u.goal_pos[2] + 0.01], yaw_quat(u.goal_rot + math.radians(1)))
    u.obj.set_pose(pose)
    u.obj_body.set_linear_velocity([math.nan, 0.0, 0.0])


def _all_finite(value) -> bool:
    if isinstance(value, dict):
        return all(_all_finite(v) for v in value.values())
    a = np.asarray(value)
    return a.dtype.kind not in "fc" or bool(np.isfinite(a).all())


@pytest.fixture(scope="module")
def ak_env():
    env = gym.make("kitbench/AssemblingKits-v1", obs_mode="state")
    yield env
    env.close()


def test_the_exploding_ring_ends_the_episode_with_a_physics_error(ak_env):
    obs0, info0 = ak_env.reset(seed=RING_SEED)
    u = ak_env.unwrapped
    assert u.episode_config()["shape"] == "ring"
    _explode_ring(u)
    obs, reward, terminated, truncated, info = ak_env.step(HOLD)
    # PhysX itself lost the ring
    assert not np.isfinite(u.obj.pose.p).all()
    assert truncated and not terminated
    assert reward == 0.0
    assert info["success"] is False
    error = info["physics_error"]
    assert "obj_to_place" in error and "non-finite position" in error and "step 1" in error
    assert "\n" not in error
    # the last finite observation and measurements: the state before the step
    np.testing.assert_array_equal(obs, obs0)
    assert _all_finite(info)
    np.testing.assert_array_equal(info["pos_diff"], info0["pos_diff"])
    # stepping on stays finite and keeps saying so; a reset gives a clean episode
    obs, reward, _, truncated, info = ak_env.step(HOLD)
    assert truncated and reward == 0.0 and np.isfinite(obs).all() and "physics_error" in info
    obs, info = ak_env.reset(seed=RING_SEED)
    obs, reward, _, truncated, info = ak_env.step(HOLD)
    assert not truncated and "physics_error" not in info and np.isfinite(reward) and np.isfinite(obs).all()


def test_a_body_thrown_faster_than_the_limit_is_a_physics_error():
    env = gym.make("kitbench/LiftPegUpright-v1", obs_mode="state_dict")
    obs0, _ = env.reset(seed=0)
    peg = env.unwrapped.peg.find_component_by_type(physx.PhysxRigidDynamicComponent)
    peg.set_linear_velocity([1000.0, 0.0, 0.0])
    obs, reward, terminated, truncated, info = env.step(np.zeros(8, dtype=np.float32))
    assert truncated and not terminated and reward == 0.0 and info["success"] is False
    assert info["physics_error"] == f"PhysX diverged at step 1: peg moves at 1e+03 m/s (limit {MAX_BODY_SPEED:g})"
    np.testing.assert_array_equal(obs["extra"]["peg_pose"], obs0["extra"]["peg_pose"])
    env.close()


def test_a_nan_velocity_is_a_physics_error():
    env = gym.make("kitbench/LiftPegUpright-v1")
    env.reset(seed=0)
    peg = env.unwrapped.peg.find_component_by_type(physx.PhysxRigidDynamicComponent)
    peg.set_linear_velocity([math.nan, 0.0, 0.0])
    obs, reward, _, truncated, info = env.step(np.zeros(8, dtype=np.float32))
    assert truncated and reward == 0.0 and np.isfinite(obs).all()
    assert "peg has a non-finite position" in info["physics_error"]
    env.close()


def test_violent_random_play_stays_well_under_the_speed_limit():
    """The limit catches solver failures only: uniform random absolute joint targets, which swing the arm hardest
    and throw the peg fastest, never come near it."""
    env = gym.make("kitbench/LiftPegUpright-v1", control_mode="pd_joint_pos")
    fastest = 0.0
    for seed in range(3):
        env.reset(seed=seed)
        peg = env.unwrapped.peg.find_component_by_type(physx.PhysxRigidDynamicComponent)
        env.action_space.seed(seed)
        while True:
            _, _, terminated, truncated, info = env.step(env.action_space.sample())
            assert "physics_error" not in info
            fastest = max(fastest, float(np.linalg.norm(peg.linear_velocity)))
            if terminated or truncated:
                break
        assert truncated and not terminated  # by the time limit
    assert 0.5 < fastest < MAX_BODY_SPEED / 2
    env.close()


class _ExplodeRing:
    """A policy that makes PhysX lose the ring (see the module docstring), then holds still."""

    def reset(self, env, seed, obs, info):
        _explode_ring(env.unwrapped)

    def act(self, obs):
        return HOLD


def test_an_exploded_episode_is_scored_as_a_physics_error(ak_env):
    result = evaluate_episode(ak_env, _ExplodeRing(), RING_SEED)
    assert not result.success and result.length == 1 and result.episode_return == 0.0
    assert result.failure == PHYSICS_ERROR
    assert result.physics_error is not None and "obj_to_place" in result.physics_error
    assert _all_finite(result.final)
    report = build_report(adhoc_suite("AssemblingKits-v1", 1, seed=RING_SEED), "explode", [result], 0.05)
    assert report["failure_categories"][PHYSICS_ERROR] == 1 and list(report["failure_categories"])[-1] == PHYSICS_ERROR
    assert report["per_episode"][0]["physics_error"] == result.physics_error
    json.dumps(report, allow_nan=False)  # no NaN from the diverged state reaches the report
    info = {"success": False, "physics_error": "x"}  # the task is not asked (it would want its own keys)
    assert failure_category(ak_env, info, GraspHistory()) == PHYSICS_ERROR
