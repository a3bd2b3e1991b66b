"""Procedural geometry and episode data for AssemblingKits (no simulator imports).

shapes    - the 20 kit shapes: outlines, exact convex pieces, symmetry, grasp widths
clearance - pocket clearance per shape, from the largest yaw a shape may fit its pocket at
fingers   - where the open fingertips come down around a shape, and how clear of obstacles they are
board     - the kit board with its pockets: collision mesh, exact convex pieces, visual mesh
episodes  - the versioned episode file format and its generator
episode_file - reading an episode file: parsed, validated, built; the packaged file written anew
convex    - polygon -> convex pieces (constrained Delaunay + Hertel-Mehlhorn), prism extrusion, meshes

The public names below are re-exported lazily (PEP 562) so that
``python -m kitbench.kits.episode_file`` does not import its own module twice and
importing the package stays cheap until geometry is actually needed.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    # The same names, imported eagerly for type checkers only: a module-level __getattr__ alone would make
    # every re-exported name Any to mypy. tests/test_kit_shapes.py holds this list equal to _EXPORTS.
    from kitbench.kits.board import (
        BOARD_MARGIN as BOARD_MARGIN,
        BOARD_SIZE as BOARD_SIZE,
        BOARD_TOP as BOARD_TOP,
        POCKET_DEPTH as POCKET_DEPTH,
        SLOT_FLOOR as SLOT_FLOOR,
        BoardGeometry as BoardGeometry,
        board_geometry as board_geometry,
        layout_problems as layout_problems,
        placed_slot_polygons as placed_slot_polygons,
    )
    from kitbench.kits.clearance import (
        DEFAULT_CLEARANCE as DEFAULT_CLEARANCE,
        MAX_SEATED_YAW as MAX_SEATED_YAW,
        SLOT_CLEARANCE as SLOT_CLEARANCE,
        max_seated_yaw as max_seated_yaw,
        required_clearance as required_clearance,
    )
    from kitbench.kits.convex import (
        convex_decompose as convex_decompose,
        extrude_convex as extrude_convex,
        extrude_mesh as extrude_mesh,
        is_convex_polygon as is_convex_polygon,
        mesh_volume as mesh_volume,
    )
    from kitbench.kits.episode_file import (
        load_episodes as load_episodes,
        validate_episodes as validate_episodes,
        write_default_episodes as write_default_episodes,
    )
    from kitbench.kits.episodes import (
        FORMAT as FORMAT,
        PALETTE as PALETTE,
        VERSION as VERSION,
        BoardSpec as BoardSpec,
        Episode as Episode,
        EpisodeFileError as EpisodeFileError,
        EpisodeSet as EpisodeSet,
        Slot as Slot,
        generate_episodes as generate_episodes,
    )
    from kitbench.kits.shapes import (
        DEFAULT_PAD_WIDTH as DEFAULT_PAD_WIDTH,
        NUM_SHAPES as NUM_SHAPES,
        SHAPE_HEIGHT as SHAPE_HEIGHT,
        SHAPE_NAMES as SHAPE_NAMES,
        SYMMETRY as SYMMETRY,
        ShapeGeometry as ShapeGeometry,
        grasp_width as grasp_width,
        narrowest_grasp as narrowest_grasp,
        place as place,
        rotational_symmetry_residual as rotational_symmetry_residual,
        shape_geometry as shape_geometry,
        shape_outline as shape_outline,
        slot_outline as slot_outline,
    )

_EXPORTS: dict[str, str] = {
    **dict.fromkeys(
        [
            "BOARD_MARGIN",
            "BOARD_SIZE",
            "BOARD_TOP",
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
        ["DEFAULT_CLEARANCE", "MAX_SEATED_YAW", "SLOT_CLEARANCE", "max_seated_yaw", "required_clearance"], "clearance"
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
        ],
        "episodes",
    ),
    **dict.fromkeys(["load_episodes", "validate_episodes", "write_default_episodes"], "episode_file"),
    **dict.fromkeys(
        [
            "DEFAULT_PAD_WIDTH",
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


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
