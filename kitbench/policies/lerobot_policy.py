"""Policies trained with `lerobot-train` (ACT, Diffusion, ...), run on kitbench envs.

The checkpoint's own pre/post-processors normalise inputs and un-normalise actions; the observations its input
features name (the cameras' parameters too) are fed under the dataset's feature names, in the layout stock
`LeRobotDataset` gave them in training (`features.as_loaded`: depth in the training run's `depth_output_unit`, point
clouds drawn with the episode's seed). A checkpoint whose inputs or action size do not match the env is refused with
both lists.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from kitbench.envs.features import (
    IMAGES,
    POINTCLOUD_PREFIX,
    as_loaded,
    obs_mode_for,
    observation_features,
    observation_frame,
)
from kitbench.envs.interface import as_kitbench
from kitbench.envs.pointcloud import DEFAULT_POINTS, PointSampler
from kitbench.errors import KitbenchError, check_choice, one_line
from kitbench.metadata import RecordingInfo
from kitbench.policies.ensemble import ENSEMBLE_OPTION, EnsembledChunks
from kitbench.policies.registry import policy_source


def _resolve(path: str) -> Path:
    p = Path(path)
    for candidate in (p, p / "pretrained_model", p / "checkpoints" / "last" / "pretrained_model"):
        if (candidate / "config.json").is_file() and (candidate / "model.safetensors").is_file():
            return candidate
    raise KitbenchError(
        f"no lerobot checkpoint at {path} (looked for config.json and model.safetensors in it, "
        f"in pretrained_model/ and in checkpoints/last/pretrained_model/)"
    )


def env_features(env, points: int = DEFAULT_POINTS) -> dict[str, tuple[int, ...]]:
    """What a kitbench env provides, under dataset names, in the shapes a policy sees (images channels first;
    `points` per point cloud)."""
    provided = {}
    for name, feature in observation_features(env, points=points).items():
        shape = tuple(feature["shape"])
        provided[name] = (shape[2], shape[0], shape[1]) if name.startswith(IMAGES) else shape
    return provided


def trained_settings(checkpoint: Path, keys: tuple[str, ...]) -> dict[str, Any]:
    """Settings of the data a checkpoint was trained on (`control_mode`, `robot`, `camera_view`, ...), read once:
    from its kitbench dataset's recording settings, else from the kitbench env it was evaluated on during training
    (None for a key neither knows). A recording without a `robot` setting was made on its task's default robot."""
    unknown = dict.fromkeys(keys)
    path = checkpoint / "train_config.json"
    if not path.is_file():
        return unknown
    train = json.loads(path.read_text())
    root = (train.get("dataset") or {}).get("root")
    if root:
        recording = RecordingInfo.read(root)
        if recording is not None:
            recording.require_current(root)  # a policy trained on another convention's actions acts otherwise here
            return {key: recording.robot_uid if key == "robot" else getattr(recording, key) for key in keys}
    env = train.get("env") or {}
    return {key: env.get(key) for key in keys} if env.get("type") == "kitbench" else unknown


def trained_setting(checkpoint: Path, key: str) -> Any:
    """One of `trained_settings`."""
    return trained_settings(checkpoint, (key,))[key]


def trained_depth_unit(checkpoint: Path) -> str:
    """The unit depth images were given to the policy in while it trained: the training run's
    `dataset.depth_output_unit`, LeRobot's default ("mm") when it names none."""
    path = checkpoint / "train_config.json"
    train = json.loads(path.read_text()) if path.is_file() else {}
    return (train.get("dataset") or {}).get("depth_output_unit") or "mm"


DEVICES = ("auto", "cpu", "cuda")


def parse_option(text: str) -> tuple[str, object]:
    """`KEY=VALUE` of `--policy-option`: the value read as JSON (`0.01`, `5`, `null`, `true`), else as text."""
    key, sep, raw = text.partition("=")
    if not sep or not key.strip():
        raise KitbenchError(f"policy option {text!r} is not KEY=VALUE (e.g. n_action_steps=5)")
    try:
        value = json.loads(raw)
    except ValueError:
        value = raw
    return key.strip(), value


def resolve_device(device: str) -> str:
    """`auto`: CUDA when torch sees it, else the CPU; `cuda` without CUDA is refused in one line."""
    check_choice("device", device, DEVICES)
    import torch

    if device == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if device == "cuda" and not torch.cuda.is_available():
        raise KitbenchError(
            f"device 'cuda': torch {torch.__version__} sees no CUDA device here; valid choices: auto, cpu"
        )
    return device


# inference settings kitbench runs itself for a policy type whose lerobot config lacks them
KITBENCH_OPTIONS = {"diffusion": (ENSEMBLE_OPTION,)}


def option_names(policy_type: str) -> set[str]:
    """Every `--policy-option` key a checkpoint of `policy_type` takes: its config's fields and kitbench's own."""
    import dataclasses

    import lerobot.policies  # noqa: F401  (registers the policy types' configs)
    from lerobot.configs import PreTrainedConfig

    fields = {f.name for f in dataclasses.fields(PreTrainedConfig.get_choice_class(policy_type))}
    return fields | set(KITBENCH_OPTIONS.get(policy_type, ()))


def apply_options(cfg, options: dict) -> None:
    """Set a checkpoint's config fields for this run (inference settings: `temporal_ensemble_coeff`,
    `n_action_steps`, `num_inference_steps`, ...), then re-run the config's own checks. A key the policy's config
    does not have, or a combination it refuses, is one line."""
    import dataclasses

    fields = {f.name for f in dataclasses.fields(cfg)}
    for key, value in options.items():
        if key not in fields:
            raise KitbenchError(
                f"policy option {key!r}: the {cfg.type} policy has no such setting; valid choices: "
                f"{', '.join(sorted(option_names(cfg.type)))}"
            )
        setattr(cfg, key, value)
    try:
        cfg.__post_init__()
    except (ValueError, TypeError, NotImplementedError) as exc:
        raise KitbenchError(
            f"policy options {options}: the {cfg.type} config refuses them: {one_line(exc, typed=False)}"
        ) from exc


class LeRobotPolicy:
    name = "lerobot"
    phase = None

    def __init__(self, checkpoint: str, device: str = "cpu", options: dict | None = None):
        """`device`: where the network runs (`resolve_device`'s choices); its inputs are built on the CPU.
        `options`: config fields set for this run (`apply_options`); on a Diffusion checkpoint
        `temporal_ensemble_coeff` is kitbench's (`policies.ensemble`): it re-plans every step and averages."""
        import torch
        from lerobot.configs import PreTrainedConfig
        from lerobot.policies import make_pre_post_processors
        from lerobot.policies.factory import get_policy_class

        device = resolve_device(device)
        path = _resolve(checkpoint)
        cfg = PreTrainedConfig.from_pretrained(path)
        cfg.device = device
        if hasattr(cfg, "pretrained_backbone_weights"):
            cfg.pretrained_backbone_weights = None  # the trained weights replace them; never download
        self.options = dict(options or {})
        settings = dict(self.options)
        ensembled = ENSEMBLE_OPTION in settings and ENSEMBLE_OPTION in KITBENCH_OPTIONS.get(cfg.type, ())
        coeff = settings.pop(ENSEMBLE_OPTION, None) if ensembled else None
        apply_options(cfg, settings)
        self._ensemble = EnsembledChunks(coeff, cfg.n_obs_steps, cfg.input_features) if ensembled else None
        self.config = cfg
        self.policy = get_policy_class(cfg.type).from_pretrained(path, config=cfg).eval()
        self.pre, self.post = make_pre_post_processors(
            cfg, pretrained_path=str(path), preprocessor_overrides={"device_processor": {"device": device}}
        )
        self.device = device
        self._torch = torch
        self.name = f"lerobot:{checkpoint}"
        self.path = path  # the pretrained_model folder
        trained = trained_settings(path, ("control_mode", "robot", "camera_view"))
        self.control_mode = trained["control_mode"]
        self.robot = trained["robot"]
        self.camera_view = trained["camera_view"]
        self.depth_unit = trained_depth_unit(path)
        self._sampler: PointSampler | None = None

    @property
    def points(self) -> int:
        """Points per cloud the policy reads (its `observation.pointcloud.xyz` input; the default when none)."""
        cloud = self.config.input_features.get(POINTCLOUD_PREFIX + "xyz")
        return int(cloud.shape[0]) if cloud is not None else DEFAULT_POINTS

    def requirements(self) -> dict:
        """What the env must provide: the obs mode that gives the policy's inputs (cameras' textures, a point
        cloud), its training control mode and robot, its cameras' size and framing."""
        needs = {}
        obs_mode = obs_mode_for(self.config.input_features)
        if obs_mode != "state":
            needs["obs_mode"] = obs_mode
        if self.control_mode is not None:
            needs["control_mode"] = self.control_mode
        if self.robot is not None:
            needs["robot"] = self.robot
        sizes = {(f.shape[-1], f.shape[-2]) for f in self.config.input_features.values() if f.type.name == "VISUAL"}
        if len(sizes) == 1:  # the cameras' size it was trained at
            width, height = sizes.pop()
            needs["camera_size"] = f"{width}x{height}"
        if obs_mode != "state" and self.camera_view is not None:  # the framing of the cameras it learned from
            needs["camera_view"] = self.camera_view
        return needs

    def check(self, env) -> None:
        env = as_kitbench(env)
        provided = env_features(env, self.points)
        expected = {k: tuple(v.shape) for k, v in self.config.input_features.items()}
        action = self.config.output_features.get("action")
        problems = [k for k in expected if provided.get(k) != expected[k]]
        if action is not None and tuple(action.shape) != tuple(env.action_space.shape):
            problems.append("action")
        if problems:
            exp = ", ".join(f"{k}{list(v)}" for k, v in sorted(expected.items()))
            prov = ", ".join(f"{k}{list(v)}" for k, v in sorted(provided.items()))
            act = list(action.shape) if action is not None else None
            raise KitbenchError(
                f"policy does not fit the env (mismatched: {', '.join(problems)}); policy expects {exp} and "
                f"action{act}; env provides {prov} and action{list(env.action_space.shape)} "
                f"({env.control_mode})"
            )

    def reset(self, env, seed, obs, info):
        self.check(env)
        self._env = env
        self._restart()
        self._torch.manual_seed(seed)  # stochastic policies (Diffusion) sample the same noise for a seed
        self._sampler = PointSampler(self.points, seed)  # the recorder draws a seed's points the same way

    def _batch(self, obs, env=None, sampler: PointSampler | None = None) -> dict:
        """One observation's inputs, unbatched, as `LeRobotDataset` gave them in training (`env`, `sampler`: those
        of the episode `obs` comes from; default: the one `reset` started)."""
        env = self._env if env is None else env
        inputs = self.config.input_features
        frame = observation_frame(env, obs, self._sampler if sampler is None else sampler)
        loaded = as_loaded({k: v for k, v in frame.items() if k in inputs}, self.depth_unit)
        batch: dict = {k: self._torch.from_numpy(v) for k, v in loaded.items()}
        batch["task"] = as_kitbench(env).task_description()
        return batch

    def _restart(self) -> None:
        """A new episode (or batch of them): nothing queued, observed or ensembled from the last one."""
        self.policy.reset()
        if self._ensemble is not None:
            self._ensemble.reset()

    def _select(self, batch: dict):
        """This step's normalised action (batch, action) from a preprocessed batch: the policy's own `select_action`,
        or with kitbench's ensembling a chunk predicted from the observation window, averaged with the earlier
        chunks' predictions for this step. The policy's own queues stay empty, so it predicts from the window."""
        if self._ensemble is None:
            return self.policy.select_action(batch)
        return self._ensemble.step(self.policy.predict_action_chunk, batch)

    def act(self, obs):
        with self._torch.inference_mode():
            action = self.post(self._select(self.pre(self._batch(obs))))
        return action.reshape(-1).cpu().numpy().astype(np.float32)

    # -- batches: several episodes in lockstep, one network call a step (`evaluation.episode.evaluate_batch`) --
    def reset_batch(self, envs: list, seeds: list[int], obs: list, infos: list[dict]) -> None:
        """Start a batch of episodes, one per env. A stochastic policy (Diffusion) draws its noise from the batch's
        first seed: the same batch always gets the same noise."""
        for env in envs:
            self.check(env)
        self._envs = list(envs)
        self._restart()
        self._torch.manual_seed(seeds[0])
        self._samplers = [PointSampler(self.points, seed) for seed in seeds]

    def act_batch(self, obs: list, active: list[bool]) -> np.ndarray:
        """(batch, action): one `select_action` over every episode of the batch. Finished episodes (`active`
        False) keep their rows, fed their last observation, so the policy's queues stay aligned with the
        batch; their actions are dropped by the caller."""
        torch = self._torch
        with torch.inference_mode():
            rows = [
                self.pre(self._batch(o, env, sampler))
                for o, env, sampler in zip(obs, self._envs, self._samplers, strict=True)
            ]
            batch = {k: torch.cat([r[k] for r in rows]) for k, v in rows[0].items() if isinstance(v, torch.Tensor)}
            batch["task"] = [t for r in rows for t in (r["task"] if isinstance(r["task"], list) else [r["task"]])]
            actions = self.post(self._select(batch))
        return actions.reshape(len(obs), -1).cpu().numpy().astype(np.float32)

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


@policy_source("lerobot", "lerobot:<checkpoint>", takes_options=True)
def _lerobot(argument: str | None, device: str, options: dict) -> LeRobotPolicy:
    return LeRobotPolicy(argument or "", device, options)
