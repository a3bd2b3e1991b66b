"""A task defined in this file alone (push a cube to a target) goes through the whole product — the env, its
scripted expert, `kitbench record` (LeRobot dataset + MCAP), `kitbench eval` and the LeRobot env plugin — with
no change to any file under kitbench/. If shared code named a task or reached into one, this would fail."""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass

import gymnasium as gym
import numpy as np
import pytest
import sapien

import kitbench
from kitbench import register_env
from kitbench.cli import main as kitbench_main
from kitbench.envs.observations import pose7
from kitbench.envs.tabletop import TabletopEnv
from kitbench.planning import CLOSED, HAND_DOWN, PhasePlanner, hold, interpolate_pose, make_pose, steps_from
from kitbench.registration import unregister_env
from kitbench.sim.cameras import CameraSpec
from kitbench.sim.scene import set_actor_pose

os.environ.setdefault("HF_HUB_OFFLINE", "1")

TASK = "PushCubeTest-v1"
HALF_SIZE = 0.02  # m
PUSH_DISTANCE = 0.1  # the goal is this far along +x from where the cube starts
GOAL_RADIUS = 0.025


class PushCubeEnv(TabletopEnv):
    """Push a cube along the table onto a goal 10 cm further from the robot."""

    environment_state_keys = ("cube_pose", "goal_pos")
    success_criteria = ("at_goal",)
    max_dense_reward = 1.0
    sensor_cameras = (CameraSpec.looking_at("base_camera", [0.3, 0, 0.6], [-0.1, 0, 0.1], 64, 48, math.pi / 2),)

    def _load_task(self, scene, render):
        builder = scene.create_actor_builder()
        builder.add_box_collision(half_size=[HALF_SIZE] * 3, density=500.0)
        if render:
            builder.add_box_visual(
                half_size=[HALF_SIZE] * 3, material=sapien.render.RenderMaterial(base_color=(0.1, 0.6, 0.2, 1.0))
            )
        self.cube = builder.build(name="cube")

    def _initialize_episode(self, rng, options):
        x, y = rng.uniform(-0.1, 0.0), rng.uniform(-0.1, 0.1)
        set_actor_pose(self.cube, [x, y, HALF_SIZE], [1.0, 0.0, 0.0, 0.0])
        self.goal = np.array([x + PUSH_DISTANCE, y, 0.0])

    def evaluate(self):
        distance = float(np.linalg.norm(self.cube.pose.p[:2] - self.goal[:2]))
        return {"success": distance < GOAL_RADIUS, "at_goal": distance < GOAL_RADIUS, "distance": distance}

    def task_state(self):
        return {"cube_pose": pose7(self.cube.pose), "goal_pos": self.goal.astype(np.float32)}

    def compute_dense_reward(self, info):
        return self.max_dense_reward if info["success"] else 1.0 - math.tanh(5.0 * info["distance"])

    def task_description(self):
        return "Push the cube onto the goal."

    @property
    def target_object(self):
        return self.cube

    def segmentation_names(self):
        return ("cube",)

    def tracked_frames(self):
        return {**super().tracked_frames(), "goal": (self.goal, np.array([1.0, 0.0, 0.0, 0.0]))}


@dataclass(frozen=True)
class PushConfig:
    speed_factor: float = 0.5
    behind: float = 0.035  # TCP behind the cube's centre at the start of the push, m
    height: float = 0.03  # TCP above the table while pushing, m


class PushCubePlanner(PhasePlanner):
    """Closed fingers come down behind the cube and push it straight onto the goal."""

    phases = ("approach", "descend", "push", "done", "failed")

    @classmethod
    def default_config(cls):
        return PushConfig()

    def _line(self, start, target, phase):
        return steps_from(
            self._timed(lambda s: interpolate_pose(start.tcp, target, s), start, min_steps=2), CLOSED, phase
        )

    def plan_next(self, finished):
        cube = self._object_pose()
        behind = cube[:3, 3] - [self.cfg.behind, 0.0, 0.0]
        if finished is None:
            above = make_pose(HAND_DOWN, [behind[0], behind[1], 0.12])
            steps = self._line(self._last(), above, "approach")
            return steps + self._line(
                steps[-1], make_pose(HAND_DOWN, [behind[0], behind[1], self.cfg.height]), "descend"
            )
        if finished == "descend":
            goal = self.env.goal
            end = make_pose(HAND_DOWN, [goal[0] - self.cfg.behind, goal[1], self.cfg.height])
            return self._line(self._last(), end, "push")
        return hold(self._last(), 1, phase="done")


PushCubeEnv.expert = PushCubePlanner


@pytest.fixture(scope="module", autouse=True)
def registered():
    """`@register_env(TASK, max_episode_steps=60)` on the class, applied while this module's tests run: at import
    time it would add the task to every other test module's task list (pytest imports them all first)."""
    register_env(TASK, max_episode_steps=60)(PushCubeEnv)
    yield
    unregister_env(TASK)
    gym.registry.pop(f"gym_kitbench/{TASK}", None)
    assert TASK not in kitbench.TASKS


def test_the_task_is_registered_through_the_public_decorator():
    assert TASK in kitbench.TASKS and kitbench.TASKS[TASK].env_class is PushCubeEnv
    env = gym.make(f"kitbench/{TASK}")
    assert env.spec.max_episode_steps == 60 and env.unwrapped.task_id == TASK
    assert PushCubeEnv.failure_categories == ("not_at_goal",)  # derived from the success criteria
    with pytest.raises(ValueError, match=f"task '{TASK}' is already registered by .*PushCubeEnv"):
        register_env(TASK, max_episode_steps=5)(type("Other", (PushCubeEnv,), {}))


def test_record_eval_and_mcap(tmp_path):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    out = tmp_path / "push"
    code = kitbench_main(
        [
            "record",
            "--task",
            TASK,
            "--episodes",
            "3",
            "--out",
            str(out),
            "--control-mode",
            "pd_joint_pos",
            "--commit-interval",
            "0",
        ]
    )
    assert code == 0
    dataset = LeRobotDataset(f"kitbench/{TASK}", root=out)  # stock lerobot reads it
    assert dataset.num_episodes == 3
    assert dataset.meta.features["observation.environment_state"]["names"] == [
        "cube_pose.x",
        "cube_pose.y",
        "cube_pose.z",
        "cube_pose.qw",
        "cube_pose.qx",
        "cube_pose.qy",
        "cube_pose.qz",
        "goal_pos.0",
        "goal_pos.1",
        "goal_pos.2",
    ]
    episodes = [json.loads(line) for line in (out / "meta/kitbench_episodes.jsonl").read_text().splitlines()]
    assert all(e["success"] for e in episodes), episodes  # the scripted expert pushes every cube home

    with open(out / "mcap" / "episode_000000.mcap", "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        frames = set()
        for _, _, _, message in reader.iter_decoded_messages(topics=["/tf"]):
            frames.update(t.child_frame_id for t in message.transforms)
        f.seek(0)
        ((_, _, _, scene),) = make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages(["/scene"])
        f.seek(0)
        phases = {json.loads(m.data)["phase"] for _, _, m in make_reader(f).iter_messages(topics=["/planner"])}
    assert {"cube", "goal", "panda_hand"} <= frames
    # its cube shows in Foxglove's 3D panel, read from the scene like every task's bodies
    (cube,) = [e for e in scene.entities if e.id == "cube"]
    assert cube.frame_id == "cube" and [cube.cubes[0].size.x, cube.cubes[0].size.z] == pytest.approx([0.04, 0.04])
    assert {"approach", "descend", "push"} <= phases <= set(PushCubePlanner.phases)  # all --noise-phases may name

    report_dir = tmp_path / "report"
    assert kitbench_main(["eval", "--task", TASK, "--episodes", "4", "--out", str(report_dir)]) == 0
    report = json.loads((report_dir / "report.json").read_text())
    assert report["success"]["count"] == 4 and list(report["criteria"]) == ["at_goal"]
    assert report["failure_categories"] == {"not_at_goal": 0, "physics_error": 0}
    assert (
        kitbench_main(["eval", "--task", TASK, "--policy", "zero", "--episodes", "2", "--out", str(tmp_path / "zero")])
        == 0
    )
    zero = json.loads((tmp_path / "zero" / "report.json").read_text())
    assert zero["failure_categories"] == {"not_at_goal": 2, "physics_error": 0}


def test_lerobot_plugin_serves_the_task():
    from lerobot.envs.factory import make_env

    from lerobot_env_kitbench import KitbenchEnvConfig

    config = KitbenchEnvConfig(task=TASK, obs_type="pixels_state", control_mode="pd_joint_pos")
    shapes = {k: tuple(v.shape) for k, v in config.features.items()}
    params = {
        f"sensor_param.base_camera.{name}": (n,)
        for name, n in [("intrinsic_cv", 9), ("extrinsic_cv", 12), ("cam2world_gl", 16)]
    }
    assert shapes == {
        "action": (8,),
        "agent_pos": (8,),
        "environment_state": (10,),
        "pixels/base_camera": (48, 64, 3),
        **params,
    }
    assert config.features_map["pixels/base_camera"] == "observation.images.base_camera"

    envs = make_env(KitbenchEnvConfig(task=TASK, control_mode="pd_joint_pos"), n_envs=2)["kitbench"][0]
    try:
        obs, _ = envs.reset(seed=[0, 1])
        assert obs["agent_pos"].shape == (2, 8) and obs["environment_state"].shape == (2, 10)
        _, _, _, _, info = envs.step(np.zeros((2, 8), dtype=np.float32))
        assert list(info["is_success"]) == [False, False]
    finally:
        envs.close()


def test_segmentation_labels_the_task_actors_it_declares(needs_vulkan):
    """`segmentation_names()` gives the cube a stable id after the robot's links; the cube's pixels and points
    carry it."""
    env = gym.make(f"kitbench/{TASK}", obs_mode="pointcloud")
    ids = env.unwrapped.segmentation_id_map
    assert list(ids.values())[-1] == "cube" and ids[0] == "background"
    obs, _ = env.reset(seed=0)
    cloud = obs["pointcloud"]
    cube = max(ids)
    on_cube = (cloud["segmentation"][:, 0] == cube) & (cloud["xyzw"][:, 3] > 0)
    assert on_cube.sum() >= 2  # 64x48 pixels: the hand hides most of the 4 cm cube at reset
    # every point labelled as the cube lies within its box (half size 2 cm, a millimetre of slack)
    centre = env.unwrapped.cube.pose.p
    assert np.abs(cloud["xyzw"][on_cube, :3] - centre).max() <= HALF_SIZE + 1e-3
    env.close()
