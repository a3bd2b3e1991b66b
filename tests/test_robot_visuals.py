"""The decimated Panda visuals keep each link's shape while cutting its triangles (CPU rendering speed)."""

from __future__ import annotations

import numpy as np
import sapien

from kitbench.robots.assets import panda_description_dir
from kitbench.robots.visuals import lightweight_mesh


def _triangles_and_bounds(path: str) -> tuple[int, np.ndarray, list]:
    shape = sapien.render.RenderShapeTriangleMesh(path)
    verts = np.concatenate([np.asarray(p.get_vertices()) for p in shape.parts])
    faces = sum(len(p.get_triangles()) for p in shape.parts)
    return faces, np.stack([verts.min(0), verts.max(0)]), [tuple(p.material.base_color[:3]) for p in shape.parts]


def test_lightweight_meshes_keep_shape_and_colours(needs_vulkan, tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    lightweight_mesh.cache_clear()
    total_before = total_after = 0
    for name in ("link0", "link4", "link6", "hand"):
        source = str(panda_description_dir() / "meshes" / "visual" / f"{name}.dae")
        light = lightweight_mesh(source)
        assert light.startswith(str(tmp_path))
        n0, b0, c0 = _triangles_and_bounds(source)
        n1, b1, c1 = _triangles_and_bounds(light)
        total_before, total_after = total_before + n0, total_after + n1
        np.testing.assert_allclose(b1, b0, atol=0.002)  # same extent to 2 mm
        assert sorted(np.round(c1, 3).tolist()) == sorted(np.round(c0, 3).tolist())  # one material per part kept
    assert total_after < total_before / 5
    lightweight_mesh.cache_clear()
