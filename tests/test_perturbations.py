"""Robustness perturbations (`kitbench.perturbations`): each changes what it says it changes, by the amount its
level says, deterministically in the episode's seed, and leaves the nominal episode's draws alone; bad names,
levels and combinations are refused in one line."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
from sapien import physx

import kitbench  # noqa: F401  (registers the tasks)
from kitbench.errors import KitbenchError
from kitbench.geometry import matrix_to_axis_angle
from kitbench.perturbations import PERTURBATIONS, Perturbations, describe
from kitbench.tasks.lift_peg_upright import LYING_QUAT, PEG_HALF_LENGTH, PEG_HALF_WIDTH

LPU = "kitbench/LiftPegUpright-v1"
AK = "kitbench/AssemblingKits-v1"


def _env(perturbations=None, **kwargs):
    return gym.make(LPU, perturbations=perturbations, **kwargs)


def _body(entity):
    return entity.find_component_by_type(physx.PhysxRigidDynamicComponent)


def _rollout(env, seed: int, steps: int, actions=None):
    """Observations of `steps` steps from `seed` with fixed seeded actions (the same for every env)."""
    rng = np.random.default_rng(7)
    obs, _ = env.reset(seed=seed)
    out = [obs]
    for _ in range(steps):
        a = env.action_space.low + rng.random(env.action_space.shape) * (env.action_space.high - env.action_space.low)
        obs, *_ = env.step(a.astype(np.float32) if actions is None else actions)
        out.append(obs)
    return np.array(out)


# -- the registry ---------------------------------------------------------------------------------------
def test_every_perturbation_the_issue_names_is_registered_and_described():
    names = set(PERTURBATIONS)
    assert {
        "camera_pose",
        "light_intensity",
        "light_color",
        "object_scale",
        "object_mass",
        "object_friction",
        "table_height",
        "qpos_noise",
        "action_noise",
        "action_delay",
        "obs_noise",
    } <= names
    for name, unit, text in describe():
        assert name in names and unit and len(text) > 20


# -- what each one changes --------------------------------------------------------------------------------
def test_object_mass_and_friction_change_the_target_object_by_their_percentage():
    nominal, heavy = _env(), _env({"object_mass": 100, "object_friction": -50})
    nominal.reset(seed=3)
    heavy.reset(seed=3)
    a, b = _body(nominal.unwrapped.peg), _body(heavy.unwrapped.peg)
    assert b.mass == pytest.approx(2 * a.mass, rel=1e-5)
    np.testing.assert_allclose(b.inertia, 2 * a.inertia, rtol=1e-5)
    for sa, sb in zip(a.collision_shapes, b.collision_shapes, strict=True):
        assert sb.physical_material.static_friction == pytest.approx(0.5 * sa.physical_material.static_friction)
        assert sb.physical_material.dynamic_friction == pytest.approx(0.5 * sa.physical_material.dynamic_friction)
    # the placement is the nominal episode's: perturbations draw from streams of their own
    np.testing.assert_array_equal(heavy.unwrapped.peg.pose.p, nominal.unwrapped.peg.pose.p)


def test_object_friction_changes_how_far_a_shoved_peg_slides():
    """Physics outcome: a peg shoved along the table at 0.5 m/s slides 1.7 cm nominal, 6.1 cm at -90% friction."""
    moved = {}
    for name, pert in (("nominal", None), ("slippery", {"object_friction": -90})):
        env = _env(pert, control_mode="pd_joint_pos")
        env.reset(seed=0)
        peg = env.unwrapped.peg
        body = _body(peg)
        start = np.array(peg.pose.p)
        body.set_linear_velocity([0.5, 0.0, 0.0])  # a shove along the table
        for _ in range(10):
            env.step(np.append(env.unwrapped.robot.qpos()[:7], -1.0).astype(np.float32))
        moved[name] = float(np.linalg.norm(np.array(peg.pose.p)[:2] - start[:2]))
    assert moved["slippery"] > 1.5 * moved["nominal"]


def test_object_scale_builds_the_peg_bigger_and_success_measures_it_as_built():
    env = _env({"object_scale": 20})
    env.reset(seed=0)
    u = env.unwrapped
    (shape,) = _body(u.peg).collision_shapes
    np.testing.assert_allclose(shape.half_size, [1.2 * PEG_HALF_LENGTH, 1.2 * PEG_HALF_WIDTH, 1.2 * PEG_HALF_WIDTH])
    assert u.peg.pose.p[2] == pytest.approx(1.2 * PEG_HALF_WIDTH, abs=1e-6)  # lying on the table
    upright = (math.cos(-math.pi / 4), 0.0, math.sin(-math.pi / 4), 0.0)  # long axis vertical
    from kitbench.sim.scene import set_actor_pose

    set_actor_pose(u.peg, [0.0, 0.0, 1.2 * PEG_HALF_LENGTH], upright)
    assert u.evaluate()["success"]
    set_actor_pose(u.peg, [0.0, 0.0, PEG_HALF_LENGTH], upright)  # the nominal peg's height: 2.4 cm too low
    assert not u.evaluate()["at_height"]
    set_actor_pose(u.peg, [0.0, 0.0, 1.2 * PEG_HALF_WIDTH], LYING_QUAT)


def test_object_scale_is_refused_by_a_task_that_does_not_build_to_measure():
    with pytest.raises(KitbenchError, match=r"object_scale is not supported by AssemblingKitsEnv"):
        gym.make(AK, perturbations={"object_scale": 10})


def test_table_height_moves_the_robot_base_down_and_leaves_the_table_and_objects():
    nominal, raised = _env(), _env({"table_height": 3})
    nominal.reset(seed=1)
    raised.reset(seed=1)
    dz = np.array(raised.unwrapped.robot.base_pose.p) - np.array(nominal.unwrapped.robot.base_pose.p)
    np.testing.assert_allclose(dz, [0, 0, -0.03], atol=1e-7)
    np.testing.assert_array_equal(raised.unwrapped.peg.pose.p, nominal.unwrapped.peg.pose.p)
    # the same joints put the hand 3 cm lower in the world: the table is 3 cm higher for the robot
    tcp_dz = raised.unwrapped.robot.tcp_pose().p[2] - nominal.unwrapped.robot.tcp_pose().p[2]
    assert tcp_dz == pytest.approx(-0.03, abs=1e-4)


def test_qpos_noise_moves_the_start_by_about_its_std_and_keeps_the_envs_own_noise():
    nominal, noisy = _env(), _env({"qpos_noise": 0.1})
    deltas = []
    for seed in range(20):
        a, _ = nominal.reset(seed=seed)
        b, _ = noisy.reset(seed=seed)
        deltas.append(b[:7] - a[:7])
    std = float(np.std(np.concatenate(deltas)))
    assert 0.07 < std < 0.13


def test_action_delay_holds_the_initial_targets_then_executes_each_action_that_many_steps_late():
    env = _env({"action_delay": 2}, control_mode="pd_joint_pos")
    obs, _ = env.reset(seed=0)
    u = env.unwrapped
    start = u.robot.arm_targets()
    actions = [np.append(obs[:7] + 0.05 * (k + 1), 1.0).astype(np.float32) for k in range(4)]
    targets = []
    for a in actions:
        env.step(a)
        targets.append(u.robot.arm_targets())
    np.testing.assert_allclose(targets[0], start, atol=1e-6)
    np.testing.assert_allclose(targets[1], start, atol=1e-6)
    np.testing.assert_allclose(targets[2], actions[0][:7], atol=1e-5)
    np.testing.assert_allclose(targets[3], actions[1][:7], atol=1e-5)


def test_action_noise_changes_the_executed_targets_by_about_its_std():
    env = _env({"action_noise": 2}, control_mode="pd_joint_pos")
    obs, _ = env.reset(seed=0)
    u = env.unwrapped
    errors = []
    for _ in range(20):
        a = np.append(obs[:7], 1.0).astype(np.float32)
        obs, *_ = env.step(a)
        errors.append(u.robot.arm_targets() - a[:7])
    std = float(np.std(errors))
    assert 0.03 < std < 0.05  # 2 units of 0.02 rad


def test_obs_noise_is_one_measurement_per_step_seen_alike_by_every_reader():
    nominal, noisy = _env(), _env({"obs_noise": 0.01})
    a, _ = nominal.reset(seed=2)
    b, _ = noisy.reset(seed=2)
    diff = b - a
    assert 0.005 < float(np.std(diff)) < 0.015
    u = noisy.unwrapped
    # the LeRobot views of the state carry the same noise as the observation
    qpos = u.state_dict()["agent"]["qpos"]
    np.testing.assert_array_equal(u.robot_state()[:7], qpos[:7])
    np.testing.assert_array_equal(u.state_dict()["agent"]["qpos"], qpos)  # read twice, measured once
    np.testing.assert_array_equal(u.environment_state()[:7], u.state_dict()["extra"]["peg_pose"])
    noisy.step(np.zeros(8, dtype=np.float32))
    assert not np.array_equal(u.state_dict()["agent"]["qpos"], qpos)  # a new step, a new measurement


@pytest.mark.parametrize(
    "perturbations",
    [
        {"qpos_noise": 0.05, "action_noise": 1.0, "obs_noise": 0.01, "action_delay": 1},
        {"object_mass": 50, "object_friction": -30, "table_height": -2, "object_scale": -10},
    ],
)
def test_perturbed_episodes_are_deterministic_in_their_seed(perturbations):
    first = _rollout(_env(perturbations), seed=5, steps=8)
    again = _env(perturbations)
    _rollout(again, seed=9, steps=3)  # another episode in between changes nothing
    np.testing.assert_array_equal(_rollout(again, seed=5, steps=8), first)
    assert not np.array_equal(_rollout(_env(perturbations), seed=6, steps=8), first)


def test_adding_a_perturbation_does_not_change_another_ones_draws():
    alone = _env({"qpos_noise": 0.1})
    both = _env({"qpos_noise": 0.1, "object_mass": 20})
    a, _ = alone.reset(seed=4)
    b, _ = both.reset(seed=4)
    np.testing.assert_array_equal(a, b)


# -- images ---------------------------------------------------------------------------------------------
def _camera_pose(env):
    cam = env.unwrapped._cameras["base_camera"]
    return cam.params()["cam2world_gl"]


@pytest.mark.render
def test_camera_pose_moves_every_camera_by_its_level_and_changes_the_image():
    nominal, jittered = _env(obs_mode="rgb"), _env({"camera_pose": 2.0}, obs_mode="rgb")
    a, _ = nominal.reset(seed=0)
    b, _ = jittered.reset(seed=0)
    pa, pb = _camera_pose(nominal), _camera_pose(jittered)
    assert np.linalg.norm(pb[:3, 3] - pa[:3, 3]) == pytest.approx(0.02, abs=1e-5)
    angle = np.linalg.norm(matrix_to_axis_angle(pb[:3, :3] @ pa[:3, :3].T))
    assert math.degrees(angle) == pytest.approx(2.0, abs=1e-3)
    image_a, image_b = a["sensor_data"]["base_camera"]["rgb"], b["sensor_data"]["base_camera"]["rgb"]
    assert np.abs(image_a.astype(int) - image_b.astype(int)).mean() > 1.0
    again, _ = _env({"camera_pose": 2.0}, obs_mode="rgb").reset(seed=0)
    np.testing.assert_array_equal(again["sensor_data"]["base_camera"]["rgb"], image_b)


@pytest.mark.render
def test_light_intensity_brightens_and_darkens_the_image():
    means = {}
    for level in (0.5, 1.0, 2.0):
        obs, _ = _env({"light_intensity": level}, obs_mode="rgb").reset(seed=0)
        means[level] = obs["sensor_data"]["base_camera"]["rgb"].astype(float).mean()
    assert means[0.5] < means[1.0] - 5 < means[2.0] - 10


@pytest.mark.render
def test_light_color_tints_the_image_deterministically():
    nominal, _ = _env(obs_mode="rgb").reset(seed=0)
    tinted, _ = _env({"light_color": 0.5}, obs_mode="rgb").reset(seed=0)
    a = nominal["sensor_data"]["base_camera"]["rgb"].astype(float).mean(axis=(0, 1))
    b = tinted["sensor_data"]["base_camera"]["rgb"].astype(float).mean(axis=(0, 1))
    ratios = b / a
    assert ratios.max() - ratios.min() > 0.1  # the channels change by different factors
    again, _ = _env({"light_color": 0.5}, obs_mode="rgb").reset(seed=0)
    np.testing.assert_array_equal(
        again["sensor_data"]["base_camera"]["rgb"], tinted["sensor_data"]["base_camera"]["rgb"]
    )


# -- bad input ------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("perturbations", "message"),
    [
        ({"camera_jitter": 1}, r"unknown perturbation 'camera_jitter'; valid choices: .*camera_pose"),
        ({"action_delay": 1.5}, r"action_delay: level must be a whole number of steps, got 1.5"),
        ({"object_mass": -100}, r"object_mass: level -100 is outside \[-90, 1000\] %"),
        ({"obs_noise": "a lot"}, r"obs_noise: level must be a number, got 'a lot'"),
        ({"camera_pose": 1}, r"camera_pose changes camera images only; obs_mode 'state' has none"),
        (["camera_pose"], r"perturbations must map a perturbation name to a level"),
    ],
)
def test_bad_perturbations_are_refused_in_one_line(perturbations, message):
    with pytest.raises(KitbenchError, match=message) as caught:
        _env(perturbations)
    assert "\n" not in str(caught.value)


def test_perturbations_apply_in_registry_order_whatever_order_they_are_given_in():
    a = Perturbations({"obs_noise": 0.1, "action_delay": 1})
    b = Perturbations({"action_delay": 1, "obs_noise": 0.1})
    assert [p.name for p in a.active] == [p.name for p in b.active]
    assert a.to_dict() == {"action_delay": 1, "obs_noise": 0.1}


def test_the_evaluation_doc_lists_every_perturbation_with_its_unit():
    from pathlib import Path

    doc = (Path(__file__).resolve().parents[1] / "docs" / "evaluation.md").read_text()
    for name, unit, _ in describe():
        assert f"| `{name}` | {unit} |" in doc, name
