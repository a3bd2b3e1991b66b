"""Policies trained with `lerobot-train` (ACT, Diffusion, ...), run on kitbench envs.

The checkpoint's own pre/post-processors normalise inputs and un-normalise actions; observations are fed under
the dataset's feature names. A checkpoint whose inputs or action size do not match the env is refused with
both lists.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kitbench.recording.rollout import robot_state


def _resolve(path: str) -> Path:
    p = Path(path)
    for candidate in (p, p / "pretrained_model", p / "checkpoints" / "last" / "pretrained_model"):
        if (candidate / "config.json").is_file() and (candidate / "model.safetensors").is_file():
            return candidate
    raise ValueError(f"no lerobot checkpoint at {path} (looked for config.json and model.safetensors in it, "
                     f"in pretrained_model/ and in checkpoints/last/pretrained_model/)")


def env_features(env) -> dict[str, tuple[int, ...]]:
    """What a kitbench env provides, under dataset names."""
    u = env.unwrapped
    provided = {"observation.state": (8,), "observation.environment_state": tuple(u.environment_state().shape)}
    for cam in u.camera_names:
        spec = u._cameras[cam].spec
        provided[f"observation.images.{cam}"] = (3, spec.height, spec.width)
    return provided


class LeRobotPolicy:
    name = "lerobot"
    phase = None

    def __init__(self, checkpoint: str):
        import torch
        from lerobot.configs import PreTrainedConfig
        from lerobot.policies import make_pre_post_processors
        from lerobot.policies.factory import get_policy_class

        path = _resolve(checkpoint)
        cfg = PreTrainedConfig.from_pretrained(path)
        cfg.device = "cpu"
        if hasattr(cfg, "pretrained_backbone_weights"):
            cfg.pretrained_backbone_weights = None  # the trained weights replace them; never download
        self.config = cfg
        self.policy = get_policy_class(cfg.type).from_pretrained(path, config=cfg).eval()
        self.pre, self.post = make_pre_post_processors(
            cfg, pretrained_path=str(path), preprocessor_overrides={"device_processor": {"device": "cpu"}})
        self._torch = torch
        self.name = f"lerobot:{checkpoint}"

    def check(self, env) -> None:
        provided = env_features(env)
        expected = {k: tuple(v.shape) for k, v in self.config.input_features.items()}
        action = self.config.output_features.get("action")
        problems = [k for k in expected if provided.get(k) != expected[k]]
        if action is not None and tuple(action.shape) != tuple(env.unwrapped.action_space.shape):
            problems.append("action")
        if problems:
            exp = ", ".join(f"{k}{list(v)}" for k, v in sorted(expected.items()))
            prov = ", ".join(f"{k}{list(v)}" for k, v in sorted(provided.items()))
            act = list(action.shape) if action is not None else None
            raise ValueError(
                f"policy does not fit the env (mismatched: {', '.join(problems)}); policy expects {exp} and "
                f"action{act}; env provides {prov} and action{list(env.unwrapped.action_space.shape)} "
                f"({env.unwrapped.control_mode})")

    def reset(self, env, seed, obs, info):
        self.check(env)
        self._env = env
        self.policy.reset()

    def _batch(self, obs) -> dict:
        torch = self._torch
        u = self._env.unwrapped
        batch = {
            "observation.state": torch.from_numpy(robot_state(u)),
            "observation.environment_state": torch.from_numpy(u.environment_state()),
            "task": u.task_description(),
        }
        for cam in u.camera_names:
            rgb = obs["sensor_data"][cam]["rgb"]
            batch[f"observation.images.{cam}"] = torch.from_numpy(np.ascontiguousarray(rgb)).permute(2, 0, 1).float() / 255.0
        return {k: v for k, v in batch.items() if k == "task" or k in self.config.input_features}

    def act(self, obs):
        with self._torch.inference_mode():
            action = self.post(self.policy.select_action(self.pre(self._batch(obs))))
        return action.reshape(-1).cpu().numpy().astype(np.float32)
