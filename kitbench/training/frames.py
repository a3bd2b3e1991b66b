"""Every camera frame of a dataset, decoded once into memory-mapped files that loader workers share.

A frame is decoded by the function stock `LeRobotDataset` calls for it (`decode_video_frames` with the dataset's
backend and tolerance, or `datasets`' own image decoding), one episode per call, so the cache holds exactly the
pixels stock would return for each row. Frames are stored channels first in the decoder's own dtype (uint8 rgb,
uint16 depth codes and 16-bit images); `FrameCache.video` and `FrameCache.images` finish them per sample with
stock's own last steps.

The cache lives under `KITBENCH_FRAME_CACHE` (default `~/.cache/kitbench/frames`), one folder per dataset state:
its key hashes the dataset's path, every data and video file's size and modification time, its `info.json`, the
episode selection and the decoder, so an edited or re-recorded dataset gets a new folder and the old one is
removed. One process builds it under a file lock while the others wait; a cache folder that cannot be written
falls back to arrays in this process's memory.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import logging
import os
import shutil
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import torch

log = logging.getLogger(__name__)

FORMAT = 1  # bump when what a cache folder holds changes
MANIFEST = "manifest.json"


def cache_root() -> Path:
    configured = os.environ.get("KITBENCH_FRAME_CACHE")
    if configured:
        return Path(configured).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "kitbench" / "frames"


def _files(root: Path) -> Iterator[Path]:
    for folder in ("data", "videos"):
        if (root / folder).is_dir():
            yield from sorted(p for p in (root / folder).rglob("*") if p.is_file())


def cache_key(root: Path, episodes: list[int] | None, backend: str | None, tolerance_s: float) -> str:
    """Changes whenever anything the cached frames were decoded from changes."""
    digest = hashlib.sha256()
    root = root.resolve()
    info = root / "meta" / "info.json"
    parts: list[Any] = [FORMAT, str(root), backend, tolerance_s, episodes]
    parts.append(hashlib.sha256(info.read_bytes()).hexdigest() if info.is_file() else None)
    for path in _files(root):
        stat = path.stat()
        parts.append([str(path.relative_to(root)), stat.st_size, stat.st_mtime_ns])
    digest.update(json.dumps(parts).encode())
    return f"{root.name}-{digest.hexdigest()[:16]}"


class Layout:
    """What the cache holds for each camera feature: `kind` (video, depth_video, image), dtype and row shape."""

    def __init__(self, rows: int, keys: dict[str, dict]):
        self.rows = rows
        self.keys = keys

    def as_json(self) -> dict:
        return {"rows": self.rows, "keys": self.keys}


class FrameCache:
    """Row-aligned frames per camera feature: `array(key)[row]` is that row's frame, channels first."""

    def __init__(self, folder: Path | None, arrays: dict[str, np.ndarray] | None = None):
        self.folder = folder
        self._arrays: dict[str, np.ndarray] = arrays or {}

    def __getstate__(self) -> dict:
        # a spawned worker maps the files again; only an in-memory cache travels as data
        return {"folder": self.folder, "arrays": {} if self.folder is not None else self._arrays}

    def __setstate__(self, state: dict) -> None:
        self.folder = state["folder"]
        self._arrays = state["arrays"]

    def array(self, key: str) -> np.ndarray:
        if key not in self._arrays:
            assert self.folder is not None
            self._arrays[key] = np.load(self.folder / _file_name(key), mmap_mode="r")
        return self._arrays[key]

    def video(self, key: str, rows: np.ndarray, as_uint8: bool) -> torch.Tensor:
        """Frames of a video feature at `rows`, (T, C, H, W), as `decode_video_frames` returns them."""
        frames = torch.from_numpy(self.array(key)[rows])
        if as_uint8 or frames.dtype != torch.uint8:
            return frames
        return frames.type(torch.float32) / 255

    def images(self, key: str, rows: np.ndarray) -> torch.Tensor:
        """Frames of an image feature at `rows`, (T, C, H, W) float32, as lerobot's `pil_to_chw_tensor` gives them."""
        frames = torch.from_numpy(self.array(key)[rows])
        if frames.dtype == torch.uint8:
            return frames.to(dtype=torch.float32).div(255)
        return frames.to(dtype=torch.float32)


def _file_name(key: str) -> str:
    return f"{key}.npy"


@contextlib.contextmanager
def _locked(path: Path) -> Iterator[None]:
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def open_or_build(
    key: str, layout: Layout, fill: Callable[[Callable[[str], np.ndarray]], None], source: Path
) -> FrameCache:
    """The cache folder `key`, built by `fill` (which writes every row of every array it is handed) unless it
    exists; in memory when the cache root cannot be written."""
    root = cache_root()
    folder = root / key
    try:
        with _locked(root / f"{key}.lock"):
            if not (folder / MANIFEST).is_file():
                _build(folder, layout, fill, source)
                _remove_stale(root, folder, source)
    except OSError as exc:
        log.warning("kitbench: frame cache under %s unusable (%s); decoding into memory", root, exc)
        arrays = {name: np.empty((layout.rows, *spec["shape"]), spec["dtype"]) for name, spec in layout.keys.items()}
        fill(arrays.__getitem__)
        return FrameCache(None, arrays)
    with contextlib.suppress(OSError):
        (root / f"{key}.lock").unlink()
    return FrameCache(folder)


def _build(folder: Path, layout: Layout, fill: Callable, source: Path) -> None:
    partial = folder.with_name(f"{folder.name}.partial-{os.getpid()}")
    if partial.exists():
        shutil.rmtree(partial)
    partial.mkdir(parents=True)
    started = time.monotonic()
    size = sum(layout.rows * int(np.prod(s["shape"])) * np.dtype(s["dtype"]).itemsize for s in layout.keys.values())
    log.info("kitbench: decoding %d frames x %d cameras of %s once into %s (%.0f MB)",
             layout.rows, len(layout.keys), source, folder, size / 1e6)  # fmt: skip
    try:
        arrays = {
            name: np.lib.format.open_memmap(
                partial / _file_name(name), "w+", spec["dtype"], (layout.rows, *spec["shape"])
            )
            for name, spec in layout.keys.items()
        }
        fill(arrays.__getitem__)
        for array in arrays.values():
            array.flush()
        del arrays
        manifest = {"format": FORMAT, "source": str(source.resolve()), **layout.as_json()}
        (partial / MANIFEST).write_text(json.dumps(manifest, indent=1))
        os.replace(partial, folder)
    finally:
        if partial.exists():
            shutil.rmtree(partial, ignore_errors=True)
    log.info("kitbench: frame cache built in %.1f s", time.monotonic() - started)


def _remove_stale(root: Path, keep: Path, source: Path) -> None:
    """Older cache folders of the same dataset (it was edited or re-recorded since)."""
    for manifest in root.glob(f"*/{MANIFEST}"):
        folder = manifest.parent
        if folder == keep:
            continue
        try:
            if json.loads(manifest.read_text()).get("source") == str(source.resolve()):
                shutil.rmtree(folder, ignore_errors=True)
        except (OSError, ValueError):
            continue


def decode_jobs(jobs: list[Callable[[], None]]) -> None:
    """Run decoding jobs on threads (the decoders release the GIL); the first error is raised."""
    workers = max(1, min(8, os.cpu_count() or 1, len(jobs)))
    if workers == 1:
        for job in jobs:
            job()
        return
    with ThreadPoolExecutor(max_workers=workers) as pool:
        for future in [pool.submit(job) for job in jobs]:
            future.result()
