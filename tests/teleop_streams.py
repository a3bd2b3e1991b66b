"""Scripted streams of a person's input derived from the expert's trajectory: the TCP targets the expert commanded
(and its hand) are followed as a person at a keyboard or a gamepad would, one control step at a time, each axis at
full deflection or still, the next waypoint taken once the commanded TCP is within half a step of it. The stream is
played through the device class (its key or stick handling) and kitbench's mapping; `follow` only chooses it."""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from kitbench.geometry import axis_angle_to_matrix, matrix_to_axis_angle
from kitbench.policies.registry import make_policy
from kitbench.registration import make_env
from kitbench.rollout import Hook, OneEpisode, run
from kitbench.teleop.mapping import commanded_tcp

AXES = ("delta_x", "delta_y", "delta_z", "delta_pitch", "delta_yaw")


@dataclass
class Waypoint:
    tcp: np.ndarray  # 4x4 base frame, the TCP the expert commanded after a step
    closed: bool  # its hand command then


class Waypoints(Hook):
    def __init__(self) -> None:
        self.start: np.ndarray | None = None
        self.points: list[Waypoint] = []
        self.success = False

    def on_reset(self, episode) -> None:
        self.start = commanded_tcp(episode.env)

    def on_action(self, episode, action, executed) -> None:
        self.closed = float(episode.env.action_to_sim(executed)[-1]) < 0

    def after_step(self, episode, step) -> None:
        self.points.append(Waypoint(commanded_tcp(episode.env), self.closed))

    def on_end(self, episode) -> None:
        self.success = episode.success


def expert_waypoints(task: str, robot: str, seed: int, mode: str = "pd_ee_target_delta_pose") -> Waypoints:
    env = make_env(task, obs_mode="state", control_mode=mode, robot_uids=robot)
    hook = Waypoints()
    try:
        run([env], [seed], OneEpisode(make_policy("expert")), lambda _: [hook])
    finally:
        env.close()
    assert hook.success, f"the expert fails {task} seed {seed} on the {robot}"
    return hook


def _rotation_error(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(matrix_to_axis_angle(a @ b.T)))


def follow(points: Waypoints, step: float, turn: float, hold: int = 30, lower: int = 0) -> list[dict[str, float]]:
    """The device's deltas (-1, 0 or 1 per axis, and lerobot's gripper class) each step, moving a commanded TCP
    with `step` metres and `turn` radians a step (the mapping's `TurnMapping.target`) through the waypoints; then
    `lower` steps down (setting down what the hand holds, as a person watching it would) and `hold` still."""
    assert points.start is not None
    current = points.start.copy()
    closed = False
    stream: list[dict[str, float]] = []
    i = 0
    combos = list(itertools.product((-1.0, 0.0, 1.0), repeat=2))
    while i < len(points.points):
        goal = points.points[i]
        error = goal.tcp[:3, 3] - current[:3, 3]
        moves = np.where(np.abs(error) > step / 2, np.sign(error), 0.0)
        # the turn (pitch about the TCP's y, yaw about the vertical) that brings the hand nearest the waypoint's
        turns = min(
            combos,
            key=lambda c: (
                _rotation_error(_turned(current[:3, :3], c, turn), goal.tcp[:3, :3]) + 1e-9 * abs(c[0] + c[1])
            ),
        )
        reached = not moves.any() and turns == (0.0, 0.0)
        gripper = 1.0
        if reached:
            if goal.closed != closed:
                closed = goal.closed
                gripper = 0.0 if closed else 2.0
            i += 1  # one waypoint a step: the expert's pauses (closing the hand) last as long
        current[:3, 3] += moves * step
        current[:3, :3] = _turned(current[:3, :3], turns, turn)
        stream.append(dict(zip(AXES, [*moves, *turns], strict=True)) | {"gripper": gripper})
    still = dict.fromkeys(AXES, 0.0) | {"gripper": 1.0}
    return stream + [still | {"delta_z": -1.0}] * lower + [still] * hold


def _turned(rotation: np.ndarray, turns: tuple[float, float], turn: float) -> np.ndarray:
    pitch, yaw = turns
    return axis_angle_to_matrix([0.0, 0.0, yaw * turn]) @ rotation @ axis_angle_to_matrix([0.0, pitch * turn, 0.0])
