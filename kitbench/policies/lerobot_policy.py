"""Policies trained with `lerobot-train` (ACT, Diffusion, ...), run on kitbench envs.

The checkpoint's own pre/post-processors normalise inputs and un-normalise actions; observations are fed under
the dataset's feature names. A checkpoint whose inputs or action size do not match the env is refused with
both lists.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from kitbench.envs.features import IMAGES, observation_features
from kitbench.errors import KitbenchError
from kitbench.metadata import read_recording_settings


def _resolve(path: str) -> Path:
    p = Path(path)
    for candidate in (p, p / "pretrained_model", p / "checkpoints" / "last" / "pretrained_model"):
        if (candidate / "config.json").is_file() and (candidate / "model.safetensors").is_file():
            return candidate
    raise KitbenchError(
        f"no lerobot checkpoint at {path} (looked for config.json and model.safetensors in it, "
        f"in pretrained_model/ and in checkpoints/last/pretrained_model/)"
    )


def env_features(env) -> dict[str, tuple[int, ...]]:
    """What a kitbench env provides, under dataset names, in the shapes a policy sees (images channels first)."""
    provided = {}
    for name, feature in observation_features(env).items():
        shape = tuple(feature["shape"])
        provided[name] = (shape[2], shape[0], shape[1]) if name.startswith(IMAGES) else shape
    return provided


def trained_setting(checkpoint: Path, key: str) -> str | None:
    """A setting of the data a checkpoint was trained on (`control_mode`, `robot`): from its kitbench dataset's
    recording settings, else from the kitbench env it was evaluated on during training (None if neither is
    known). A recording without a `robot` setting was made on its task's default robot."""
    path = checkpoint / "train_config.json"
    if not path.is_file():
        return None
    train = json.loads(path.read_text())
    root = (train.get("dataset") or {}).get("root")
    if root:
        recording = read_recording_settings(root)
        if recording is not None:
            value = recording.get(key)
            if value is None and key == "robot" and recording.get("task"):
                from kitbench.registration import task_entry

                value = task_entry(recording["task"]).env_class.supported_robots[0]
            return value
    env = train.get("env") or {}
    return env.get(key) if env.get("type") == "kitbench" else None


def trained_control_mode(checkpoint: Path) -> str | None:
    """The control mode of the actions a checkpoint was trained on (`trained_setting`)."""
    return trained_setting(checkpoint, "control_mode")


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
            cfg, pretrained_path=str(path), preprocessor_overrides={"device_processor": {"device": "cpu"}}
        )
        self._torch = torch
        self.name = f"lerobot:{checkpoint}"
        self.control_mode = trained_control_mode(path)
        self.robot = trained_setting(path, "robot")

    def requirements(self) -> dict:
        """What the env must provide: camera images if the policy reads any, its training control mode."""
        needs = {}
        if any(k.startswith("observation.images.") for k in self.config.input_features):
            needs["obs_mode"] = "rgb"
        if self.control_mode is not None:
            needs["control_mode"] = self.control_mode
        if self.robot is not None:
            needs["robot"] = self.robot
        return needs

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
            raise KitbenchError(
                f"policy does not fit the env (mismatched: {', '.join(problems)}); policy expects {exp} and "
                f"action{act}; env provides {prov} and action{list(env.unwrapped.action_space.shape)} "
                f"({env.unwrapped.control_mode})"
            )

    def reset(self, env, seed, obs, info):
        self.check(env)
        self._env = env
        self.policy.reset()
        self._torch.manual_seed(seed)  # stochastic policies (Diffusion) sample the same noise for a seed

    def _batch(self, obs) -> dict:
        torch = self._torch
        u = self._env.unwrapped
        batch = {
            "observation.state": torch.from_numpy(u.robot_state()),
            "observation.environment_state": torch.from_numpy(u.environment_state()),
            "task": u.task_description(),
        }
        for cam in u.camera_names:
            rgb = obs["sensor_data"][cam]["rgb"]
            batch[f"observation.images.{cam}"] = (
                torch.from_numpy(np.ascontiguousarray(rgb)).permute(2, 0, 1).float() / 255.0
            )
        return {k: v for k, v in batch.items() if k == "task" or k in self.config.input_features}

    def act(self, obs):
        with self._torch.inference_mode():
            action = self.post(self.policy.select_action(self.pre(self._batch(obs))))
        return action.reshape(-1).cpu().numpy().astype(np.float32)

    def action_chunk(self, obs) -> np.ndarray:
        """The (chunk, action) actions the policy predicts from `obs` alone, un-normalised, without touching what
        `act` has queued or ensembled: what comparing a policy with a label, step by step, needs. ACT only: a
        policy that predicts from a history of observations (Diffusion) has no chunk for one observation."""
        if self.config.type != "act":
            raise KitbenchError(f"action_chunk needs an ACT policy (one observation a chunk), got {self.config.type}")
        with self._torch.inference_mode():
            chunk = self.policy.predict_action_chunk(self.pre(self._batch(obs)))
            steps = [self.post(chunk[:, t]).reshape(-1).cpu().numpy() for t in range(chunk.shape[1])]
        return np.stack(steps).astype(np.float32)
