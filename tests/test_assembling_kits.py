"""AssemblingKits-v1: success flags on constructed poses, insertion physics per shape, reliability."""

from __future__ import annotations

import json
import math
import resource

import gymnasium as gym
import numpy as np
import pytest
import sapien

import kitbench  # noqa: F401
from kitbench.geometry import axis_quat, matrix_to_quat, quat_to_matrix, yaw_quat
from kitbench.kits import SYMMETRY, EpisodeFileError
from kitbench.tasks.assembling_kits import AssemblingKitsEnv, signed_yaw_error, yaw_error

TASK = "kitbench/AssemblingKits-v1"
HOLD = np.array([0, 0, 0, 0, 0, 0, 0, -1], dtype=np.float32)


@pytest.fixture(scope="module")
def env():
    e = gym.make(TASK, obs_mode="state_dict").unwrapped
    yield e
    e.close()


def _episode_with_target(env, shape_id: int) -> int:
    return next(i for i, e in enumerate(env.episodes) if e.target_shape_id == shape_id)


def _place(env, dx=0.0, dy=0.0, dz=0.0, dyaw=0.0, tilt=0.0):
    p = env.goal_pos + np.array([dx, dy, dz])
    q = yaw_quat(env.goal_rot + dyaw)
    if tilt:  # rolled about its own x axis, as a shape resting on one edge
        q = matrix_to_quat(quat_to_matrix(q) @ quat_to_matrix(axis_quat([1, 0, 0], tilt)))
    env.obj.set_pose(sapien.Pose(p, q))
    return env.evaluate()


# -- the yaw rule ----------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "yaw,goal,sym,expected",
    [
        (0.1, 0.0, 2 * math.pi, 0.1),
        (-3.1, 3.1, 2 * math.pi, 2 * math.pi - 6.2),  # across the +-pi seam
        (math.pi / 2 + 0.01, 0.0, math.pi / 2, 0.01),  # a square turned a quarter is the same square
        (2 * math.pi / 3 - 0.02, 0.0, 2 * math.pi / 3, 0.02),
        (1.234, 0.0, 0.0, 0.0),  # disc: any yaw
    ],
)
def test_yaw_error_modulo_symmetry(yaw, goal, sym, expected):
    assert yaw_error(yaw, goal, sym) == pytest.approx(expected, abs=1e-9)
    assert abs(signed_yaw_error(yaw, goal, sym)) == pytest.approx(expected, abs=1e-9)


def test_signed_yaw_error_is_the_turn_to_make():
    assert signed_yaw_error(0.1, 0.0, 2 * math.pi) == pytest.approx(-0.1)
    assert signed_yaw_error(3.1, -3.1, 2 * math.pi) == pytest.approx(2 * math.pi - 6.2)  # across the seam
    assert signed_yaw_error(0.0, math.pi / 2 - 0.01, math.pi / 2) == pytest.approx(-0.01)  # square: back a little


# -- success flags on constructed poses ------------------------------------------------------------
def test_seated_at_goal_pose_is_success_and_each_flag_fails_independently(env):
    env.reset(seed=0, options={"episode_index": _episode_with_target(env, 0)})  # asymmetric L block
    info = _place(env)
    assert info["success"] and info["pos_correct"] and info["rot_correct"] and info["in_slot"]
    info = _place(env, dx=0.025, dz=0.0)
    assert (info["pos_correct"], info["rot_correct"], info["in_slot"], info["success"]) == (False, True, True, False)
    assert info["pos_diff_norm"] == pytest.approx(0.025, abs=1e-6)
    info = _place(env, dyaw=math.radians(5))
    assert (info["pos_correct"], info["rot_correct"], info["in_slot"], info["success"]) == (True, False, True, False)
    assert info["rot_diff"] == pytest.approx(math.radians(5), abs=1e-6)
    info = _place(env, dyaw=math.radians(3.5))
    assert info["rot_correct"]
    info = _place(env, dz=0.004)
    assert (info["pos_correct"], info["rot_correct"], info["in_slot"], info["success"]) == (True, True, False, False)
    assert _place(env, dz=0.0025)["in_slot"]


def test_symmetric_equivalents_are_accepted(env):
    env.reset(seed=0, options={"episode_index": _episode_with_target(env, 3)})  # square, pi/2
    assert _place(env, dyaw=math.pi / 2)["success"]
    assert _place(env, dyaw=-math.pi / 2 + math.radians(2))["success"]
    assert not _place(env, dyaw=math.pi / 4)["rot_correct"]
    env.reset(seed=0, options={"episode_index": _episode_with_target(env, 0)})  # asymmetric
    assert not _place(env, dyaw=math.pi)["rot_correct"]


@pytest.mark.parametrize("shape_id", [11, 16])
def test_disc_and_ring_accept_any_yaw(env, shape_id):
    env.reset(seed=0, options={"episode_index": _episode_with_target(env, shape_id)})
    for dyaw in np.linspace(0, 2 * math.pi, 7):
        assert _place(env, dyaw=dyaw)["success"]


def test_yaw_is_read_robustly_from_a_tilted_shape(env):
    env.reset(seed=0, options={"episode_index": _episode_with_target(env, 0)})
    info = _place(env, dz=0.0, dyaw=math.radians(2), tilt=math.radians(20))
    assert info["rot_diff"] == pytest.approx(math.radians(2), abs=math.radians(0.5))


def test_goal_fields_seat_the_shape(env):
    obs, _ = env.reset(seed=5)
    extra = obs["extra"]
    assert set(extra) >= {
        "obj_pose",
        "tcp_to_obj_pos",
        "goal_pos",
        "goal_rot",
        "obj_to_goal_pos",
        "shape_id",
        "symmetry",
    }
    assert extra["symmetry"][0] == pytest.approx(SYMMETRY[int(extra["shape_id"][0])])
    env.obj.set_pose(sapien.Pose(extra["goal_pos"], yaw_quat(float(extra["goal_rot"][0]))))
    assert env.evaluate()["success"]


@pytest.mark.parametrize("shape_id", [0, 7, 11, 16])
def test_policy_state_codes_the_shape_and_folds_its_yaw_by_symmetry(env, shape_id):
    """LeRobot's environment state: the shape one-hot, and the shape's yaw folded by its symmetry (the same
    for every equivalent yaw, different for a yaw that is not equivalent)."""
    env.reset(seed=0, options={"episode_index": _episode_with_target(env, shape_id)})
    names = env.environment_state_names()

    def field(name):
        state = env.environment_state()
        return state[[i for i, n in enumerate(names) if n.startswith(name + ".")]]

    onehot = field("shape_onehot")
    assert onehot.sum() == 1.0 and int(np.argmax(onehot)) == shape_id
    symmetry = SYMMETRY[shape_id]
    folded = []
    for yaw in (0.3, 0.3 + symmetry, 0.3 + math.radians(10)):
        env.obj.set_pose(sapien.Pose([0.05, 0.1, 0.05], yaw_quat(yaw)))
        folded.append(field("obj_yaw_sym"))
    np.testing.assert_allclose(folded[0], folded[1], atol=1e-5)
    if symmetry > 0:
        assert np.linalg.norm(folded[0] - folded[2]) > 0.1
    else:  # a disc or ring: every yaw is the same
        np.testing.assert_allclose(folded[0], folded[2], atol=1e-5)
    assert np.linalg.norm(folded[0]) == pytest.approx(1.0)


def test_policy_state_gives_the_turns_a_hand_regulates(env):
    """The hand's yaw over the shape's, folded by the gripper's two-fold symmetry, and the turn still needed to the
    goal, folded by the shape's: [1, 0] when aligned, whichever equivalent yaw, and off it otherwise."""
    env.reset(seed=0, options={"episode_index": _episode_with_target(env, 0)})  # asymmetric L block
    names = env.environment_state_names()

    def field(name):
        state = env.environment_state()
        return state[[i for i, n in enumerate(names) if n.startswith(name + ".")]]

    tcp_yaw = math.atan2(*field("tcp_yaw")[::-1])
    for turn in (0.0, math.pi):  # fingers closing the same way
        env.obj.set_pose(sapien.Pose([0.05, 0.1, 0.05], yaw_quat(tcp_yaw + 0.4 + turn)))
        np.testing.assert_allclose(field("tcp_to_obj_yaw"), [math.cos(0.8), math.sin(0.8)], atol=1e-4)
    _place(env)
    np.testing.assert_allclose(field("obj_to_goal_yaw"), [1.0, 0.0], atol=1e-5)
    _place(env, dyaw=-0.3)
    np.testing.assert_allclose(field("obj_to_goal_yaw"), [math.cos(0.3), math.sin(0.3)], atol=1e-4)


def test_policy_state_resolves_the_insertions_millimetre(env):
    """`obj_to_goal_fine` is the shape-to-goal offset and the signed turn on the scale the insertion is corrected at:
    0 when seated, a millimetre or a degree moves it by a large fraction of its range, and it saturates on the way;
    `tcp_to_obj_fine` the same for the grasp at a centimetre."""
    env.reset(seed=0, options={"episode_index": _episode_with_target(env, 0)})  # asymmetric L block
    names = env.environment_state_names()

    def field(name):
        return env.environment_state()[[i for i, n in enumerate(names) if n.startswith(name + ".")]]

    _place(env)
    np.testing.assert_allclose(field("obj_to_goal_fine"), [0.0, 0.0, 0.0], atol=1e-4)
    _place(env, dx=0.001, dyaw=math.radians(-1.0))  # goal - shape: -1 mm in x, +1 degree to turn
    np.testing.assert_allclose(field("obj_to_goal_fine"), [math.tanh(-1 / 3), 0.0, math.tanh(0.5)], atol=2e-3)
    symmetry = SYMMETRY[0]
    _place(env, dyaw=symmetry - math.radians(1.0))  # the same turn, one symmetry period around
    assert field("obj_to_goal_fine")[2] == pytest.approx(math.tanh(0.5), abs=2e-3)
    _place(env, dx=-0.05, dy=0.05)
    np.testing.assert_allclose(field("obj_to_goal_fine")[:2], [1.0, -1.0], atol=1e-4)
    tcp = env.robot.tcp_pose().p
    env.obj.set_pose(sapien.Pose([tcp[0] + 0.005, tcp[1] - 0.02, 0.05], yaw_quat(0.0)))
    np.testing.assert_allclose(field("tcp_to_obj_fine"), [math.tanh(0.5), math.tanh(-2.0)], atol=1e-3)


# -- physics (drops into every default kit: tests/test_kit_physics.py) ------------------------------
def test_seated_shape_keeps_success_for_200_steps(env):
    env.reset(seed=0, options={"episode_index": _episode_with_target(env, 10)})
    _place(env)
    for _ in range(200):
        _, _, terminated, _, info = env.step(HOLD)
        assert info["success"] and terminated


def test_shapes_do_not_tunnel_through_board_or_table(env):
    for seed in range(12):
        env.reset(seed=seed)
        rest = env.obj.pose.p.copy()
        env.obj.set_pose(sapien.Pose(rest + [0, 0, 0.1], env.obj.pose.q))  # drop from 10 cm, under the hand
        for _ in range(30):
            env.step(HOLD)
        z = env.obj.pose.p[2]
        assert z > rest[2] - 0.004, f"seed {seed}: fell from {rest[2] + 0.1:.3f} to {z:.4f}"


def test_spawn_is_flat_clear_of_pockets_and_in_region(env):
    for seed in range(30):
        obs, info = env.reset(seed=seed)
        p = obs["extra"]["obj_pose"]
        assert -0.1 <= p[0] <= 0.1 and -0.182 <= p[1] <= 0.182
        assert p[2] == pytest.approx(0.021, abs=1e-6) or p[2] == pytest.approx(0.001, abs=1e-6)
        assert not info["success"]


def test_episode_choice_follows_the_seed(env):
    a = [env.reset(seed=s) and env.episode_index for s in range(10)]
    b = [env.reset(seed=s) and env.episode_index for s in range(10)]
    assert a == b and len(set(a)) > 5


def test_same_seed_same_actions_bitwise_identical():
    def rollout(e, seed):
        obs, _ = e.reset(seed=seed)
        rng = np.random.default_rng(seed)
        out = [obs]
        for _ in range(40):
            obs, *_ = e.step(rng.uniform(-1, 1, 8).astype(np.float32))
            out.append(obs)
        return np.stack(out)

    e1 = gym.make(TASK)
    first = rollout(e1, 3)
    rollout(e1, 4)
    np.testing.assert_array_equal(first, rollout(e1, 3))
    np.testing.assert_array_equal(first, rollout(gym.make(TASK), 3))


# -- bad input -------------------------------------------------------------------------------------
def test_bad_episode_index(env):
    with pytest.raises(ValueError, match=r"episode_index 300 out of range; valid choices: 0..299"):
        env.reset(seed=0, options={"episode_index": 300})


def test_robot_must_have_the_wrist_camera():
    with pytest.raises(
        ValueError, match="robot 'panda' is not supported by AssemblingKitsEnv; valid choices: panda_wristcam"
    ):
        gym.make(TASK, robot_uids="panda")


def test_bad_episode_file_names_file_and_field(tmp_path):
    from kitbench.kits import generate_episodes

    data = generate_episodes(n=3, seed=1)
    data["episodes"][1]["slots"][0]["shape_id"] = 42
    path = tmp_path / "mine.json"
    path.write_text(json.dumps(data))
    with pytest.raises(EpisodeFileError, match=r"mine.json: episodes\[1\].slots\[0\].shape_id"):
        AssemblingKitsEnv(episode_file=path)


def test_user_episode_file_is_used(tmp_path):
    from kitbench.kits import generate_episodes

    path = tmp_path / "two.json"
    path.write_text(json.dumps(generate_episodes(n=2, seed=7)))
    e = AssemblingKitsEnv(episode_file=path)
    assert len(e.episodes) == 2
    e.reset(seed=0, options={"episode_index": 1})
    assert e.episode.target_shape_id == e.episodes[1].target_shape_id


# -- reliability -----------------------------------------------------------------------------------
def _rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * resource.getpagesize() / 2**20


def test_thousand_resets_do_not_grow_memory():
    e = gym.make(TASK).unwrapped
    for s in range(50):
        e.reset(seed=s)
    before = _rss_mb()
    for s in range(50, 1050):
        e.reset(seed=s)
    after = _rss_mb()
    assert after <= before * 1.05, f"RSS grew from {before:.1f} MB to {after:.1f} MB over 1000 resets"


def test_check_env_with_both_cameras(needs_vulkan):
    from gymnasium.utils.env_checker import check_env

    e = gym.make(TASK, obs_mode="rgbd", render_mode="rgb_array")
    check_env(e.unwrapped)
    obs, _ = e.reset(seed=1)
    assert set(obs["sensor_data"]) == {"base_camera", "hand_camera"}
    for cam in obs["sensor_data"].values():
        assert cam["rgb"].shape == (128, 128, 3) and cam["rgb"].std() > 5
    # the hand camera looks along the gripper: straight down at the ready pose, so it sees the table/kit
    # within the 0.2 m below the hand rather than the far floor
    depth = obs["sensor_data"]["hand_camera"]["depth"]
    assert 0.05 < float(np.median(depth)) < 0.35
    assert e.render().shape == (512, 512, 3)
