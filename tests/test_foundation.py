"""The installation itself: imports, doctor, rendering, and one kinematic model shared by SAPIEN and MuJoCo."""

from __future__ import annotations

import os
import subprocess
import sys

import mujoco
import numpy as np
import sapien

import kitbench
from kitbench.control.kinematics import ArmKinematics, arm_model
from kitbench.geometry import look_at, pose_to_matrix
from kitbench.robots import ROBOTS, Robot
from kitbench.robots.assets import panda_urdf_path
from kitbench.robots.panda import READY_ARM_QPOS
from kitbench.sim.scene import SimConfig, create_scene

KITBENCH = [sys.executable, "-m", "kitbench.cli"]


def test_package_imports_and_registers_tasks():
    import gymnasium as gym

    assert kitbench.__version__
    assert "kitbench/LiftPegUpright-v1" in gym.registry
    assert gym.registry["kitbench/LiftPegUpright-v1"].max_episode_steps == 50


def test_doctor_passes_and_names_the_device(needs_vulkan):
    out = subprocess.run([*KITBENCH, "doctor"], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "all checks passed" in out.stdout
    vulkan_line = next(line for line in out.stdout.splitlines() if " vulkan " in line)
    assert vulkan_line.startswith("ok")
    if "llvmpipe" in vulkan_line:
        assert "CPU software renderer" in vulkan_line


def test_doctor_fails_clearly_without_vulkan():
    env = {**os.environ, "VK_ICD_FILENAMES": "/nonexistent", "VK_DRIVER_FILES": "/nonexistent"}
    out = subprocess.run([*KITBENCH, "doctor"], capture_output=True, text=True, timeout=300, env=env)
    assert out.returncode != 0
    assert "no usable Vulkan device" in out.stdout
    assert "mesa-vulkan-drivers" in out.stdout


def test_panda_scene_renders_a_non_blank_image(needs_vulkan):
    scene = create_scene(SimConfig(), render=True)
    scene.set_ambient_light([0.4, 0.4, 0.4])
    scene.add_directional_light([0, 1, -1], [1, 1, 1])
    robot = Robot(scene, ROBOTS["panda"], sapien.Pose([0, 0, 0]), render=True)
    robot.reset(READY_ARM_QPOS)
    camera = scene.add_camera("c", 128, 128, 1.0, 0.01, 10)
    p, q = look_at([1.2, 0.0, 0.6], [0.0, 0.0, 0.4])
    camera.set_local_pose(sapien.Pose(p, q))
    scene.update_render()
    camera.take_picture()
    rgb = camera.get_picture("Color")[..., :3]
    segmentation = camera.get_picture("Segmentation")[..., 1]  # actor-level ids; 0 is background
    assert rgb.std() > 0.05
    assert (segmentation > 0).mean() > 0.05, "the robot covers too little of the image"


def test_mujoco_compiles_the_same_urdf_with_hand_and_tcp_bodies():
    model = arm_model(ROBOTS["panda"])
    bodies = {model.body(i).name for i in range(model.nbody)}
    assert {"panda_link7", "panda_hand", "panda_hand_tcp", "panda_leftfinger"} <= bodies
    assert model.nq == 9
    assert str(panda_urdf_path()).endswith("panda.urdf")


def test_mujoco_and_sapien_agree_on_the_tcp_pose():
    """Controller, planner and simulator share one kinematic model: FK must match to the micrometre."""
    scene = create_scene(SimConfig(), render=False)
    robot = Robot(scene, ROBOTS["panda"], sapien.Pose([0, 0, 0]), render=False)
    kin = ArmKinematics(ROBOTS["panda"])
    rng = np.random.default_rng(0)
    for _ in range(10):
        q = rng.uniform(robot.arm_limits[:, 0], robot.arm_limits[:, 1])
        robot.reset(q)
        sim = robot.tcp_pose()
        mj = kin.tcp_pose(q)
        np.testing.assert_allclose(pose_to_matrix(sim.p, sim.q), mj, atol=2e-5)
    assert mujoco.__version__


def test_panda_has_no_self_contacts_at_rest():
    """Hand and wrist links overlap by design; a contact between them would fight the solver every step."""
    scene = create_scene(SimConfig(), render=False)
    robot = Robot(scene, ROBOTS["panda"], sapien.Pose([0, 0, 0]), render=False)
    rng = np.random.default_rng(1)
    for q in [READY_ARM_QPOS, *rng.uniform(robot.arm_limits[:, 0], robot.arm_limits[:, 1], (5, 7))]:
        robot.reset(q)
        scene.step()
        pairs = {
            (c.bodies[0].entity.name, c.bodies[1].entity.name)
            for c in scene.get_contacts()
            if min(p.separation for p in c.points) < 0
        }
        assert not {p for p in pairs if p in {("panda_hand", "panda_link7"), ("panda_link7", "panda_hand")}}
    robot.reset(READY_ARM_QPOS)
    scene.step()
    assert not [c for c in scene.get_contacts() if min(p.separation for p in c.points) < 0]
