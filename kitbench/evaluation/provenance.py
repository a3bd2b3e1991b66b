"""What produced a report (`report["provenance"]`): the weights scored, the settings the policy ran with, the
suite, the software, the machine and the command.

- `policy`: the policy argument and, for a lerobot checkpoint, its folder, the sha256 of each of its files (weights,
  configs, normaliser statistics) and of all of them together, the training step, and the dataset it was trained
  on (repo id, root, episode count and kitbench's episodes digest when the root is a kitbench recording).
- `execution`: the settings in force once the checkpoint's config and every `--policy-option` are applied, read
  from the loaded policy (policy type, chunk size, action steps, ensembling, inference steps, observation steps,
  device, dtype), the batch size, the inference latency (`action_delay`, control steps) and the options themselves.
- `suite`: a digest of what decides the numbers (`Suite.to_dict()` less its name, description and file) and the
  env settings the episodes ran in (the arguments of `make_env`, the control and simulation rates).
- `software`: versions of Python and the packages that decide an episode; `vulkan`: the render device and the
  installed Vulkan drivers, only when episodes are scored from camera images (the device then exists already:
  none is created for this); `machine`: CPU model and cores, the GPU a network ran on; `source`: the git commit
  and whether the tree had changes, when kitbench runs from a checkout; `command`: the command line.

`OUTCOME_KEYS` are the sections whose differences can change an outcome; `kitbench compare` prints them, and a
resumed evaluation refuses to continue across them.
"""

from __future__ import annotations

import hashlib
import importlib.metadata as md
import json
import os
import platform
import shlex
import subprocess
import sys
from pathlib import Path
from typing import Any

import kitbench
from kitbench.evaluation.suite import Suite

# the policy config fields that decide how a checkpoint turns observations into actions
EXECUTION_FIELDS = (
    "chunk_size",
    "horizon",
    "n_action_steps",
    "n_obs_steps",
    "temporal_ensemble_coeff",
    "num_inference_steps",
)
# where the installed Vulkan drivers (ICDs) are listed; VK_ICD_FILENAMES / VK_DRIVER_FILES override them
ICD_DIRS = ("/usr/share/vulkan/icd.d", "/etc/vulkan/icd.d")
NVIDIA_VERSION = Path("/proc/driver/nvidia/version")
# (section, what it holds) of a report's provenance whose differences can change an outcome
OUTCOME_KEYS = (("execution", "execution"), ("software", "version"), ("vulkan", "vulkan"))


def sha256_file(path: Path) -> str:
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


def checkpoint_files(folder: Path) -> dict[str, str]:
    """sha256 of every file of a checkpoint folder (`model.safetensors`, `config.json`, the processors' files), by
    name."""
    return {p.name: sha256_file(p) for p in sorted(folder.iterdir()) if p.is_file()}


def training_step(folder: Path) -> int | None:
    """The training step a `lerobot-train` checkpoint was saved at: its `training_state/training_step.json`, else
    its folder's name (`checkpoints/<step>/pretrained_model`)."""
    step_file = folder.parent / "training_state" / "training_step.json"
    try:
        return int(json.loads(step_file.read_text())["step"])
    except (OSError, ValueError, KeyError, TypeError):
        pass
    name = folder.resolve().parent.name
    return int(name) if name.isdigit() else None


def _dataset(folder: Path) -> dict | None:
    """The dataset a checkpoint was trained on, as its `train_config.json` names it."""
    from kitbench.metadata import RecordingInfo, lerobot_info

    path = folder / "train_config.json"
    try:
        dataset = json.loads(path.read_text()).get("dataset") or {}
    except (OSError, ValueError, AttributeError):
        return None
    root = dataset.get("root")
    out: dict[str, Any] = {"repo_id": dataset.get("repo_id"), "root": root, "episodes": None, "episodes_sha256": None}
    if root and Path(root).is_dir():
        try:
            out["episodes"] = lerobot_info(Path(root)).get("total_episodes")
            recording = RecordingInfo.read(root)
        except Exception:  # noqa: BLE001 - a dataset moved or damaged since training: its name still stands
            recording = None
        if recording is not None:
            out["episodes_sha256"] = recording.episodes_sha256
    return out


def checkpoint(policy) -> dict | None:
    """A lerobot checkpoint's folder, file digests, training step and dataset (None for other policies)."""
    folder = getattr(policy, "path", None)
    if folder is None or not getattr(policy, "name", "").startswith("lerobot:"):
        return None
    folder = Path(folder)
    files = checkpoint_files(folder)
    together = hashlib.sha256("".join(f"{name}\0{digest}\n" for name, digest in files.items()).encode())
    return {
        "path": str(folder.resolve()),
        "sha256": together.hexdigest(),
        "files": files,
        "training_step": training_step(folder),
        "dataset": _dataset(folder),
    }


def execution(policy, spec: str, device: str, batch_size: int, options: dict, action_delay: int = 0) -> dict:
    """The settings the policy runs with, read from it: a checkpoint's config once the options are applied (and
    the inference steps its model actually takes), the device and dtype its network runs in, and the control steps
    between an observation and the execution of the action computed from it (`action_delay`)."""
    out: dict[str, Any] = {"policy_type": spec.partition(":")[0], "batch_size": batch_size}
    config = getattr(policy, "config", None)
    network = getattr(policy, "policy", None)
    if config is not None:
        out["policy_type"] = config.type
        out.update({key: getattr(config, key) for key in EXECUTION_FIELDS if hasattr(config, key)})
        steps = getattr(getattr(network, "diffusion", None), "num_inference_steps", None)
        if steps is not None:  # None in the config means the training schedule's length
            out["num_inference_steps"] = int(steps)
        from kitbench.policies.ensemble import ENSEMBLE_OPTION

        # a config without the field (Diffusion) is ensembled by kitbench when the option is given; None: off
        out.setdefault(ENSEMBLE_OPTION, options.get(ENSEMBLE_OPTION))
    parameters = getattr(network, "parameters", None)
    parameter = next(iter(parameters()), None) if callable(parameters) else None
    out["device"] = device if parameter is not None else None
    out["dtype"] = str(parameter.dtype).removeprefix("torch.") if parameter is not None else None
    out["action_delay"] = action_delay
    out["policy_options"] = dict(options)
    return out


def suite_digest(suite: Suite) -> str:
    """sha256 of what decides a suite's numbers (its name, description and file do not)."""
    decides = {k: v for k, v in suite.to_dict().items() if k not in ("name", "description", "source")}
    return hashlib.sha256(json.dumps(decides, sort_keys=True).encode()).hexdigest()


def versions() -> dict[str, str | None]:
    from kitbench.doctor import PACKAGES

    found: dict[str, str | None] = {"python": platform.python_version()}
    for name in dict.fromkeys((*PACKAGES, "numpy")):
        try:
            found[name] = md.version(name)
        except md.PackageNotFoundError:
            found[name] = None
    return found


def _icd_files() -> list[Path]:
    listed = os.environ.get("VK_ICD_FILENAMES") or os.environ.get("VK_DRIVER_FILES")
    if listed:
        return [Path(p) for p in listed.split(os.pathsep) if p]
    return sorted(p for folder in ICD_DIRS if Path(folder).is_dir() for p in Path(folder).glob("*.json"))


def vulkan() -> dict:
    """The render device SAPIEN uses (made already by the caller's env) and the installed Vulkan drivers: each
    ICD's library and Vulkan API version, and NVIDIA's kernel driver version where there is one."""
    import sapien

    device = sapien.render.RenderSystem().device
    drivers = {}
    for path in _icd_files():
        try:
            icd = json.loads(path.read_text()).get("ICD") or {}
        except (OSError, ValueError, AttributeError):
            continue
        drivers[path.name] = f"{icd.get('library_path')} (Vulkan {icd.get('api_version')})"
    nvidia = NVIDIA_VERSION.read_text().splitlines()[0].strip() if NVIDIA_VERSION.is_file() else None
    return {"device": device.name, "drivers": drivers, "nvidia_driver": nvidia}


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.partition(":")[2].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine(device: str | None) -> dict:
    gpu = None
    if device == "cuda":
        import torch

        gpu = torch.cuda.get_device_name()
    return {"cpu": _cpu_model(), "cores": os.cpu_count(), "gpu": gpu, "platform": platform.platform()}


def source() -> dict | None:
    """The git commit kitbench runs from and whether its tracked files have changes (None outside a checkout)."""
    root = Path(kitbench.__file__).resolve().parents[1]
    if not (root / ".git").exists():
        return None
    try:
        commit = subprocess.run(
            ["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=10, check=True
        ).stdout.strip()
        status = subprocess.run(
            ["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=10,
            check=True,
        ).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    return {"git_commit": commit, "dirty": bool(status.strip())}


def command_line() -> str:
    """The command that makes the report from scratch: this one, less `--resume` and `--stop-after N` (how far a
    run goes now, not what it scores), with kitbench's own entry point (`kitbench`, `python -m kitbench.cli`)
    named `kitbench`."""
    program = Path(sys.argv[0])
    ours = program.name == "kitbench" or program.resolve() == Path(kitbench.__file__).resolve().parent / "cli.py"
    kept: list[str] = []
    args = iter(sys.argv[1:])
    for arg in args:
        if arg == "--stop-after":
            next(args, None)
        elif arg != "--resume" and not arg.startswith("--stop-after="):
            kept.append(arg)
    return shlex.join(["kitbench" if ours else sys.argv[0], *kept])


def provenance(
    spec: str,
    policy,
    suite: Suite,
    env: dict,
    device: str,
    batch_size: int,
    options: dict,
    renders: bool,
    action_delay: int = 0,
) -> dict:
    """The report's provenance (see the module docstring); `env`: the env settings the episodes run in, `renders`:
    whether the episodes are scored from camera images, `action_delay`: the inference latency run (`execution`)."""
    uses_network = callable(getattr(getattr(policy, "policy", None), "parameters", None))
    found = {
        "policy": {"spec": spec, "checkpoint": checkpoint(policy)},
        "execution": execution(policy, spec, device, batch_size, options, action_delay),
        "suite": {"digest": suite_digest(suite), "env": env},
        "software": versions(),
        "vulkan": vulkan() if renders else None,
        "machine": machine(device if uses_network else None),
        "source": source(),
        "command": command_line(),
    }
    return plain(found)


def plain(value):
    """`value` as JSON reads it back (tuples as lists, numpy numbers as Python's): what a journal holds and a
    report says, so that a resumed run compares equal to the run it continues."""

    def default(obj):
        if hasattr(obj, "tolist"):
            return obj.tolist()
        raise TypeError(f"{type(obj).__name__} is not JSON")

    return json.loads(json.dumps(value, default=default))


def _flat(prefix: str, value) -> dict[str, Any]:
    if isinstance(value, dict):
        out: dict[str, Any] = {}
        for key, inner in value.items():
            out.update(_flat(f"{prefix}.{key}", inner))
        return out
    return {prefix: value}


def outcome_differences(a: dict | None, b: dict | None, names: tuple[str, str] = ("A", "B")) -> list[str]:
    """Each difference between two provenances that can change an outcome (execution settings, versions, the
    Vulkan driver), one line each, naming both values; reports without provenance have none to compare."""
    if not a or not b:
        return []
    lines = []
    for key, label in OUTCOME_KEYS:
        if a.get(key) is None or b.get(key) is None:  # scored from images in one only: the suites say so
            continue
        fa, fb = _flat(key, a.get(key)), _flat(key, b.get(key))
        for name in dict.fromkeys([*fa, *fb]):
            va, vb = fa.get(name), fb.get(name)
            if va != vb:
                shown = name.removeprefix(f"{key}.")
                lines.append(f"{label} {shown}: {names[0]} {va!r}, {names[1]} {vb!r}")
    return lines
