"""`kitbench doctor`: is this machine ready to simulate, render and decode video?

Each check reports a line; the exit status is non-zero when any required check fails, with a message that
says what to install or run.
"""

from __future__ import annotations

import importlib.metadata as md
import platform
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

from kitbench.errors import one_line

SOFTWARE_RENDERERS = ("llvmpipe", "lavapipe", "swiftshader", "softpipe")
PACKAGES = ("kitbench", "sapien", "mujoco", "mink", "torch", "lerobot", "gymnasium", "mcap")


@dataclass
class Check:
    name: str
    ok: bool
    detail: str
    fix: str = ""


def check_versions() -> list[Check]:
    checks = [
        Check(
            "python",
            sys.version_info[:2] == (3, 12),
            platform.python_version(),
            "kitbench needs Python 3.12 (lerobot 0.6 requires it)",
        )
    ]
    for name in PACKAGES:
        try:
            checks.append(Check(name, True, md.version(name)))
        except md.PackageNotFoundError:
            checks.append(Check(name, False, "not installed", "run `make test` (or `uv sync --frozen`)"))
    return checks


def check_vulkan() -> Check:
    """Create SAPIEN's render system and name the Vulkan device it picked."""
    fix = (
        "no usable Vulkan device: run `make demo` as root to install one (Mesa >= 25 `mesa-vulkan-drivers` "
        "for CPU rendering, from bookworm-backports on Debian 12), or install your GPU's Vulkan driver and "
        "`libvulkan1`. State-only simulation works without it."
    )
    try:
        import sapien

        device = sapien.render.RenderSystem().device
        name = device.name
    except Exception as exc:  # noqa: BLE001 - any failure here means "cannot render"
        return Check("vulkan", False, one_line(exc), fix)
    kind = "CPU software renderer" if any(s in name.lower() for s in SOFTWARE_RENDERERS) else "GPU"
    return Check("vulkan", True, f"{name} ({kind})")


def vulkan_error() -> str | None:
    """The line `kitbench doctor` gives when this machine cannot render (None when it can), for commands that
    need camera images to refuse before they write anything."""
    check = check_vulkan()
    return None if check.ok else f"{check.detail}: {check.fix}"


def require_renderer(obs_mode: str) -> None:
    """Refuse an image observation mode on a machine that cannot render, with the doctor's line: without a
    renderer the env fails deep inside SAPIEN, after output folders exist."""
    from kitbench.envs.modes import IMAGE_OBS_MODES
    from kitbench.errors import KitbenchError

    if obs_mode in IMAGE_OBS_MODES:
        error = vulkan_error()
        if error is not None:
            raise KitbenchError(f"obs_mode {obs_mode!r} needs camera images: {error}")


def check_video_decoding() -> Check:
    """Encode a tiny clip with ffmpeg and decode it with torchcodec, the way lerobot reads datasets."""
    fix = "install FFmpeg (`apt-get install ffmpeg`, done by `make test` when root) for torchcodec video decoding"
    try:
        with tempfile.TemporaryDirectory() as tmp:
            clip = Path(tmp) / "probe.mp4"
            subprocess.run(
                [
                    "ffmpeg",
                    "-loglevel",
                    "error",
                    "-f",
                    "lavfi",
                    "-i",
                    "testsrc=size=64x64:rate=10:duration=0.5",
                    "-pix_fmt",
                    "yuv420p",
                    "-c:v",
                    "libx264",
                    str(clip),
                ],
                check=True,
                capture_output=True,
                timeout=60,
            )
            from torchcodec.decoders import VideoDecoder

            frames = VideoDecoder(str(clip))[:]
            n = int(frames.shape[0])
    except FileNotFoundError:
        return Check("video", False, "ffmpeg not found", fix)
    except Exception as exc:  # noqa: BLE001 - any failure here means "cannot decode"
        return Check("video", False, one_line(exc), fix)
    return Check("video", n == 5, f"ffmpeg + torchcodec decode ok ({n} frames)", fix)


def check_ray() -> Check:
    """Ray is optional (`--executor ray`): its absence is reported, never a failure. Says which cluster `auto`
    would join."""
    try:
        version = md.version("ray")
    except md.PackageNotFoundError:
        return Check("ray", True, "not installed (optional: --executor ray needs pip install 'kitbench[ray]')")
    from kitbench.engine.ray_executor import running_cluster

    cluster = running_cluster()
    where = f"joins the cluster at {cluster}" if cluster else "no cluster running: starts a local one on loopback"
    return Check("ray", True, f"{version}; --executor ray --ray-address auto {where}")


def check_fetch_assets() -> Check:
    """The Fetch robot's model, installed at set-up time from the package index (`make bootstrap`)."""
    from kitbench.robots.fetch_assets import INSTALL_HINT, source

    where = source()
    if "override" in where:
        found = f"{where['path']} (from {where['override']})"
        missing = f"{where['override']}={where['path']} has no fetch.urdf"
        fix = f"point {where['override']} at the folder holding fetch.urdf, or unset it and {INSTALL_HINT}"
    else:
        found = f"{where['path']} (from {where['wheel']}, sha256 {where['sha256'][:12]})"
        missing = f"missing at {where['path']}"
        fix = INSTALL_HINT
    return Check("fetch model", where["present"], found if where["present"] else missing, fix)


def check_bf16() -> Check:
    """Whether the CPU camera configs' bf16 autocast runs here, or they train in fp32 (never a failure)."""
    import torch

    from kitbench.training.precision import cpu_bf16

    capability, bf16 = torch.backends.cpu.get_cpu_capability(), cpu_bf16()
    if bf16 is None:
        detail = f"unknown ({platform.machine()}, {capability}): the CPU camera configs train as written"
    elif bf16:
        detail = f"yes ({capability}): the CPU camera configs train under bf16 autocast"
    else:
        detail = (
            f"no ({capability}): the CPU camera configs train in fp32 here (--policy.use_amp=false; docs/training.md)"
        )
    return Check("cpu bf16", True, detail)


def run_doctor(stream=sys.stdout) -> int:
    checks = [
        *check_versions(),
        check_vulkan(),
        check_video_decoding(),
        check_ray(),
        check_fetch_assets(),
        check_bf16(),
    ]
    width = max(len(c.name) for c in checks)
    for c in checks:
        print(f"{'ok ' if c.ok else 'BAD'} {c.name:<{width}}  {c.detail}", file=stream)
    failed = [c for c in checks if not c.ok]
    for c in failed:
        print(f"\n{c.name}: {c.fix}", file=stream)
    print("\nall checks passed" if not failed else f"\n{len(failed)} check(s) failed", file=stream)
    return 1 if failed else 0
