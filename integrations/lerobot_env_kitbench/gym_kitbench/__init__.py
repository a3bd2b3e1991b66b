"""Gymnasium ids `gym_kitbench/<Task>` with LeRobot's observation names (lerobot imports `gym_<env.type>`)."""

from lerobot_env_kitbench.env import register_lerobot_envs

register_lerobot_envs()
