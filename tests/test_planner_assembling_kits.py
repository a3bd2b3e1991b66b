"""The AssemblingKits-v1 expert: real insertions on a fixed seed set, and its wrist/yaw choice."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

import kitbench  # noqa: F401
from kitbench.geometry import planar_yaw, quat_to_matrix
from kitbench.planning.assembling_kits import AssemblingKitsPlanner
from kitbench.planning.kit_grasps import across_narrowest, signed_yaw_options
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


@pytest.mark.parametrize(
    "angle,grasp_angle,symmetry,expected",
    [
        (90.0, 0.0, 90.0, True),  # a square: across either pair of sides
        (45.0, 0.0, 90.0, False),  # ...not across its corners
        (36.0, 0.0, 72.0, True),  # a pentagon: a turn by 72 degrees and the hand's half turn make 36
        (18.0, 0.0, 72.0, False),
        (179.0, 1.0, 360.0, True),  # no symmetry: closing along a direction or its opposite is one grasp
        (30.0, 1.0, 360.0, False),
        (30.0, 1.0, 0.0, True),  # a disc: every direction
        (3.0, 0.0, 360.0, False),  # more than half a sampled direction (2.5 degrees) off
    ],
)
def test_the_narrowest_grasp_is_recognised_up_to_the_shapes_symmetry(angle, grasp_angle, symmetry, expected):
    assert across_narrowest(math.radians(angle), math.radians(grasp_angle), math.radians(symmetry)) is expected


def _closes_across_narrowest(env, seed: int, prefer: bool) -> bool:
    env.reset(seed=seed)
    u = env.unwrapped
    planner = u.make_expert({"prefer_narrowest": prefer})
    start = planner._last()
    turn, _ = planner._choose_grasp(start)
    closing = planar_yaw(start.tcp[:3, :3]) + turn - math.pi / 2  # the fingers close across the hand's y
    angle = closing - planar_yaw(quat_to_matrix(u.obj.pose.q))
    return across_narrowest(angle, u.shape.grasp_angle, u.shape.symmetry)


@pytest.mark.parametrize("seed", [1, 6, 17, 21])  # a hexagon, a kite, a pentagon, a square
def test_prefer_narrowest_closes_across_the_shapes_narrowest_width(env, seed):
    """`prefer_narrowest`: the shape sits in the hand at one yaw per shape; the shipped expert closes any way."""
    assert not _closes_across_narrowest(env, seed, False)
    assert _closes_across_narrowest(env, seed, True)


@pytest.mark.parametrize("seed", [6, 17])
def test_the_expert_closing_across_the_narrowest_width_inserts_the_shape(seed):
    from kitbench.policies.expert import ExpertPolicy

    env = gym.make("kitbench/AssemblingKits-v1", control_mode="pd_joint_pos")
    try:
        policy = ExpertPolicy({"prefer_narrowest": True})
        obs, info = env.reset(seed=seed)
        policy.reset(env, seed, obs, info)
        for _ in range(200):
            obs, _, terminated, truncated, info = env.step(policy.act(obs))
            if terminated or truncated:
                break
    finally:
        env.close()
    assert info["success"]


@pytest.mark.parametrize("seed", [10, 24])  # an asymmetric shape 96 degrees off its slot, a rectangle 71
def test_turn_over_slot_carries_the_shape_unturned_and_turns_it_over_its_slot(seed):
    """`turn_over_slot`: through the transport the hand keeps its yaw until the shape is over its slot, then turns
    there, in place, by the whole turn; the shape goes in. The shipped expert turns on the way."""
    from kitbench.policies.expert import ExpertPolicy

    def transport(options: dict) -> tuple[list[tuple[float, float]], bool]:
        env = gym.make("kitbench/AssemblingKits-v1", control_mode="pd_joint_pos")
        try:
            policy = ExpertPolicy(options)
            obs, info = env.reset(seed=seed)
            policy.reset(env, seed, obs, info)
            u = env.unwrapped
            goal = np.asarray(u.goal_pos[:2], dtype=float)
            path = []  # (hand's yaw, shape's distance from the slot) each transport step
            for _ in range(200):
                obs, _, terminated, truncated, info = env.step(policy.act(obs))
                if policy.planner.phase == "transport":
                    tcp = policy.planner._tcp()
                    path.append((planar_yaw(tcp[:3, :3]), float(np.linalg.norm(u.obj.pose.p[:2] - goal))))
                if terminated or truncated:
                    break
            return path, bool(info["success"])
        finally:
            env.close()

    path, success = transport({"turn_over_slot": True})
    assert success
    yaws = np.unwrap([y for y, _ in path])
    far = [i for i, (_, d) in enumerate(path) if d > 0.02]  # on the way, before the shape is over its slot
    assert far and np.max(np.abs(yaws[far] - yaws[0])) < math.radians(3)
    assert abs(yaws[-1] - yaws[0]) > math.radians(20)  # then the whole turn, over the slot
    shipped, success = transport({})
    turned = np.unwrap([y for y, _ in shipped])
    far = [i for i, (_, d) in enumerate(shipped) if d > 0.02]
    assert success and np.max(np.abs(turned[far] - turned[0])) > math.radians(10)


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


# -- studies/assembling_kits_grasp/grasp_misses.py: where a policy closes the hand, against the expert ----------------
def test_grasp_misses_reads_where_the_hand_closes():
    """The expert against itself closes the same way, clear of the obstacles, and the hand then holds the shape at
    about the width that direction needs; a policy that never closes the hand reads as such."""
    from studies.assembling_kits_grasp.grasp_misses import measure

    (row,) = measure("expert", [1_000_000], None)
    assert row["policy"] == row["expert"]
    close = row["expert"]
    assert close["clearance_mm"] > 10.0 and close["success"]
    assert 20.0 < close["hand_above_mm"] < 35.0 and close["offset_xy_mm"] < 3.0
    assert abs(close["opening_after_mm"] - close["needs_mm"]) < 6.0  # squeezing the shape, not the air
    (idle,) = measure("zero", [1_000_000], "pd_ee_delta_pose")
    assert idle["policy"] is None and idle["expert"] == close


def test_grasp_misses_refuses_what_it_cannot_replay(tmp_path, capsys):
    from studies.assembling_kits_grasp.grasp_misses import main

    report = tmp_path / "report.json"
    report.write_text('{"task": "AssemblingKits-v1", "failure_categories": {"dropped": 1}, "per_episode": []}')
    assert main(["--policy", "expert", "--report", str(report), "--failure", "sideways"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "'sideways'" in err and "never_grasped" in err
    assert main(["--policy", "expert", "--report", str(report)]) == 2  # no episode ended never_grasped
    report.write_text('{"task": "LiftPegUpright-v1", "per_episode": []}')
    assert main(["--policy", "expert", "--report", str(report)]) == 2
    assert "LiftPegUpright-v1" in capsys.readouterr().err
    assert main(["--policy", "expert", "--seeds", "1,x"]) == 2


def test_a_flat_jaw_meets_a_face_across_a_rectangle_and_a_corner_of_a_triangle():
    from kitbench.planning.kit_grasps import CLOSING_SAMPLES, jaw_contacts

    along = jaw_contacts(6)[0]  # the 50 x 24 mm rectangle closed along its length: a 24 mm face at either end
    assert along.behind_at == pytest.approx(-0.025) and along.ahead_at == pytest.approx(0.025)
    assert along.behind_face == pytest.approx(0.024, abs=5e-4) and along.ahead_face == pytest.approx(0.024, abs=5e-4)
    diagonal = jaw_contacts(6)[CLOSING_SAMPLES // 4]  # at 45 degrees a jaw meets a corner on either side
    assert diagonal.behind_face < 0.002 and diagonal.ahead_face < 0.002
    # the triangle (apex up) closed along y: its base is a face behind, its apex a corner ahead
    up = jaw_contacts(2)[CLOSING_SAMPLES // 2]
    assert up.behind_face == pytest.approx(0.044, abs=5e-4) and up.ahead_face < 0.002
    small = jaw_contacts(6, 0.7)[0]  # and at 0.7 scale, everything 0.7 as far
    assert small.behind_at == pytest.approx(-0.0175) and small.behind_face == pytest.approx(0.0168, abs=5e-4)


# -- bench/expert_assembling_kits.py: how often a shape sits in the hand at one yaw ---------------------------------
def test_the_expert_bench_reads_the_shapes_yaw_in_the_hand_as_the_narrowest_grasp_puts_it():
    from bench.expert_assembling_kits import run_seeds
    from kitbench.kits import shape_geometry

    (episode,) = run_seeds(([6], "pd_joint_pos", "panda_wristcam", {"prefer_narrowest": True}, None))
    assert episode.success and episode.grip is not None
    grip, period = episode.grip
    shape = shape_geometry(episode.shape_id)
    # the fingers close across the narrowest width, the hand's y along it: the shape sits a quarter turn off it
    expected = math.degrees(-shape.grasp_angle - math.pi / 2) % period
    apart = abs(grip - expected) % period
    assert min(apart, period - apart) < 4.0


def test_one_grip_counts_the_episodes_near_the_commonest_yaw_in_the_hand_across_the_fold():
    from bench.expert_assembling_kits import Episode, one_grip

    def at(*grips: float, period: float = 90.0) -> list[Episode]:
        return [Episode(0, 3, True, 50, "success", (g, period)) for g in grips]

    assert one_grip(at(1.0, 88.0, 45.0)) == (2, 3)  # 1 and 88 are 3 degrees apart on a square's fold
    assert one_grip(at(1.0, 20.0, 45.0)) == (1, 3)
    assert one_grip(at(0.0, 0.0, period=0.0)) == (2, 2)  # a disc sits alike at every yaw
    assert one_grip([Episode(0, 3, False, 200, "never grasped", None)]) == (0, 0)


@pytest.mark.parametrize("seed", [3, 15])  # a chevron and an L-block, jammed at the slot by the plans at the limits
def test_in_measured_end_effector_deltas_the_expert_plans_what_the_hand_follows(seed):
    """In `pd_ee_delta_pose` each action leads the measured hand by at most 0.1 rad, of which ManiSkill's drives
    cover part in a step: planned at the joint limits the hand fell behind, reached the slot still turning and
    jammed the shape there; each joint kept to `ee_delta_tracking` of the bound a step, it seats it."""
    from kitbench.planning.planner import MEASURED_DELTA_TRACKING
    from kitbench.policies.joint_targets import joint_target_to_action

    env = gym.make("kitbench/AssemblingKits-v1", control_mode="pd_ee_delta_pose")
    outcomes = {}
    for tracking in (None, MEASURED_DELTA_TRACKING):
        obs, info = env.reset(seed=seed)
        planner = env.unwrapped.make_expert({"ee_delta_tracking": tracking})
        bound = 0.1 / planner.dt  # rad/s: the action bound a step
        assert (planner.max_velocity <= MEASURED_DELTA_TRACKING * bound * (1 + 1e-6)).all() == (tracking is not None)
        terminated = truncated = False
        while not (terminated or truncated):
            target = planner.act(obs)
            obs, _, terminated, truncated, info = env.step(joint_target_to_action(env, target[:-1], float(target[-1])))
        outcomes[tracking] = (bool(info["success"]), bool(info["in_slot"]))
    env.close()
    assert outcomes[None] == (False, False) and outcomes[MEASURED_DELTA_TRACKING][0], outcomes


@pytest.mark.parametrize("bad", [0, -0.4, 1.5])
def test_a_tracking_share_outside_the_bound_is_refused_in_one_line(bad):
    from kitbench.errors import KitbenchError

    env = gym.make("kitbench/AssemblingKits-v1", control_mode="pd_ee_delta_pose")
    env.reset(seed=0)
    with pytest.raises(KitbenchError, match=rf"ee_delta_tracking must be within \(0, 1\].*got {float(bad)}$"):
        env.unwrapped.make_expert({"ee_delta_tracking": bad})
    env.close()
