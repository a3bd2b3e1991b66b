"""Lightweight Panda visual meshes for CPU rendering.

The example-robot-data Panda visuals carry 135k triangles; on a software Vulkan device they cost ~50 ms of the
~57 ms a 128x128 camera frame takes. Each link's mesh is decimated once per machine (quadric simplification,
per material part so the colours survive) into OBJ files in the user's cache folder; later runs just load them.
"""

from __future__ import annotations

import functools
import hashlib
import os
import tempfile
from pathlib import Path

import numpy as np

from kitbench.robots.spec import Decimation

DEFAULT = Decimation()  # coincident vertices welded, 12% of each part's triangles kept
_FORMAT_VERSION = 2


def cache_dir() -> Path:
    """The user's cache folder, or the temp folder where the home directory is not writable."""
    name = f"panda-visuals-v{_FORMAT_VERSION}-{int(DEFAULT.keep * 100)}"
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "kitbench"
    try:
        base.mkdir(parents=True, exist_ok=True)
        if os.access(base, os.W_OK):
            return base / name
    except OSError:
        pass
    return Path(tempfile.gettempdir()) / f"kitbench-{os.getuid()}" / name


def _write_obj(path: Path, parts: list[tuple[np.ndarray, np.ndarray, tuple[float, float, float]]]) -> None:
    """One OBJ with a material group per part (plain text: no mesh library needed)."""
    mtl = path.with_suffix(".mtl")
    lines = [f"mtllib {mtl.name}"]
    mtl_lines = []
    offset = 1
    for i, (vertices, faces, color) in enumerate(parts):
        mtl_lines += [f"newmtl part{i}", "Kd {:.4f} {:.4f} {:.4f}".format(*color), "Ks 0.1 0.1 0.1", "Ns 20", ""]
        lines += [f"o part{i}", f"usemtl part{i}"]
        lines += ["v {:.6f} {:.6f} {:.6f}".format(*v) for v in vertices]
        lines += ["f {} {} {}".format(*(f + offset)) for f in faces]
        offset += len(vertices)
    # per-process names: workers (test workers, recording workers) may make the same mesh at once
    tmp = path.with_suffix(f".{os.getpid()}.tmp")
    mtl_tmp = mtl.with_suffix(f".{os.getpid()}.mtltmp")
    mtl_tmp.write_text("\n".join(mtl_lines))
    tmp.write_text("\n".join(lines) + "\n")
    os.replace(mtl_tmp, mtl)
    os.replace(tmp, path)  # the OBJ appears last: its presence means the pair is complete


def _weld(vertices: np.ndarray, faces: np.ndarray, weld: float = DEFAULT.weld) -> tuple[np.ndarray, np.ndarray]:
    """Merge vertices within `weld` of each other (on a grid that fine): the meshes split vertices per face, which
    decimation cannot collapse; a coarser grid also merges a CAD export's sliver triangles, dropping those it
    collapses to a line or a point."""
    keys = np.round(vertices / weld).astype(np.int64)
    _, index, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    faces = inverse.reshape(-1)[faces]
    if weld != DEFAULT.weld:
        faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])]
    return vertices[index], faces


def _decimate(
    vertices: np.ndarray, faces: np.ndarray, decimation: Decimation = DEFAULT
) -> tuple[np.ndarray, np.ndarray]:
    import fast_simplification

    vertices, faces = _weld(vertices, faces, decimation.weld)
    if len(faces) < 200:
        return vertices, faces
    v, f = fast_simplification.simplify(
        vertices.astype(np.float32), faces.astype(np.int64), target_reduction=1.0 - decimation.keep
    )
    return v, f


@functools.cache
def lightweight_mesh(source: str, decimation: Decimation = DEFAULT) -> str:
    """Path of the decimated copy of a visual mesh file (`Decimation`), made on first use."""
    import sapien

    digest = hashlib.sha1(Path(source).read_bytes()).hexdigest()[:12]
    how = "" if decimation == DEFAULT else f"-weld{decimation.weld * 1e6:g}um-keep{decimation.keep * 100:g}"
    target = cache_dir() / f"{Path(source).stem}-{digest}{how}.obj"
    if target.is_file():
        return str(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    shape = sapien.render.RenderShapeTriangleMesh(source)
    parts = []
    for part in shape.parts:
        v, f = _decimate(np.asarray(part.get_vertices()), np.asarray(part.get_triangles()), decimation)
        r, g, b = (float(c) for c in part.material.base_color[:3])
        parts.append((v, f, (r, g, b)))
    _write_obj(target, parts)
    return str(target)
