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


def test_the_so101s_meshes_welded_coarser_decimate_far_and_keep_their_extent(needs_vulkan, tmp_path, monkeypatch):
    import re
    from pathlib import Path

    from kitbench.robots import ROBOTS

    spec = ROBOTS["so101"]
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    lightweight_mesh.cache_clear()
    urdf = Path(spec.urdf())
    names = ("wrist_roll_follower_so101_v1.stl", "moving_jaw_so101_v1.stl")  # each stalled at 50% and 37% before
    meshes = [m for m in re.findall(r'filename="([^"]+\.stl)"', urdf.read_text()) if Path(m).name in names]
    assert len(set(meshes)) == 2
    for mesh in sorted(set(meshes)):
        source = str(urdf.parent.parent / mesh.split("so_arm_description/")[1])
        fine, coarse = lightweight_mesh(source), lightweight_mesh(source, spec.decimate_visuals)
        assert fine != coarse  # each its own cached copy
        n0, b0, _ = _triangles_and_bounds(source)
        n1, b1, _ = _triangles_and_bounds(coarse)
        np.testing.assert_allclose(b1, b0, atol=0.001)  # same extent to 1 mm
        assert n1 < 0.2 * n0 and n1 < 0.6 * _triangles_and_bounds(fine)[0]
    lightweight_mesh.cache_clear()
