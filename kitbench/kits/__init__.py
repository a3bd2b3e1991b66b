"""Procedural geometry and episode data for AssemblingKits (no simulator imports).

shapes   - the 20 kit shapes: outlines, exact convex pieces, symmetry, grasp widths
board    - the kit board with its pockets, as exact convex pieces plus a visual mesh
episodes - the versioned episode file format, its generator and validating loader
convex   - polygon -> convex pieces (constrained Delaunay + Hertel-Mehlhorn) and prism extrusion

The public names below are re-exported lazily (PEP 562) so that
``python -m kitbench.kits.episodes`` does not import its own module twice and
importing the package stays cheap until geometry is actually needed.
"""

from __future__ import annotations

import importlib

_EXPORTS: dict[str, str] = {
    **dict.fromkeys(
        [
            "BOARD_MARGIN",
            "BOARD_SIZE",
            "BOARD_TOP",
            "DEFAULT_CLEARANCE",
            "POCKET_DEPTH",
            "SLOT_FLOOR",
            "BoardGeometry",
            "board_geometry",
            "layout_problems",
            "placed_slot_polygons",
        ],
        "board",
    ),
    **dict.fromkeys(
        ["convex_decompose", "extrude_convex", "extrude_mesh", "is_convex_polygon", "mesh_volume"], "convex"
    ),
    **dict.fromkeys(
        [
            "FORMAT",
            "PALETTE",
            "VERSION",
            "BoardSpec",
            "Episode",
            "EpisodeFileError",
            "EpisodeSet",
            "Slot",
            "generate_episodes",
            "load_episodes",
            "validate_episodes",
            "write_default_episodes",
        ],
        "episodes",
    ),
    **dict.fromkeys(
        [
            "FINGER_PAD_WIDTH",
            "MAX_GRASP_WIDTH",
            "NUM_SHAPES",
            "SHAPE_HEIGHT",
            "SHAPE_NAMES",
            "SYMMETRY",
            "ShapeGeometry",
            "grasp_width",
            "narrowest_grasp",
            "place",
            "rotational_symmetry_residual",
            "shape_geometry",
            "shape_outline",
            "slot_outline",
        ],
        "shapes",
    ),
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
