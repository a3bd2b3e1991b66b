"""AssemblingKits episodes: the schema (version 2; version 1 is still read) and the generator; reading and validating
a file is `kitbench.kits.episode_file`.

An episode fixes everything random about a kit scene except the loose
object's start pose: which shapes sit in which pockets at which yaw, which one
the robot must place, which are already seated, and the colours.  Episodes
are data, not code, so datasets recorded on one kitbench version can be
replayed on another; the format is documented in
docs/assembling-kits-episodes.md and versioned.

    python -m kitbench.kits.episode_file      # regenerate the packaged file
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from kitbench.errors import KitbenchError
from kitbench.kits.board import (
    BOARD_MARGIN,
    BOARD_SIZE,
    BOARD_TOP,
    POCKET_DEPTH,
    SLOT_FLOOR,
    BoardGeometry,
    Clearance,
    SlotPose,
    board_geometry,
    layout_problems,
    placed_slot_polygons,
    pocket_clearances,
)
from kitbench.kits.clearance import DEFAULT_CLEARANCE, SLOT_CLEARANCE
from kitbench.kits.shapes import NUM_SHAPES, check_scale

FORMAT = "kitbench/assembling-kits-episodes"
# Version 2: `board.clearance` may be one clearance per shape id; the generator writes kitbench's own
# (clearance.SLOT_CLEARANCE). A version 1 file (one clearance for every pocket, 2 mm by default) reads as it always
# did.
VERSION = 2
READABLE_VERSIONS = (1, 2)
SLOTS_PER_KIT = 5
DEFAULT_EPISODES = 300
DEFAULT_FILE = "episodes.json"
ROUND_DIGITS = 5  # 1e-5 m / rad: far below the smallest clearance (0.69 mm), keeps the file small

# Ten well-separated object colours (Tableau-10 without its grey, plus yellow).
PALETTE: tuple[tuple[float, float, float], ...] = (
    (0.122, 0.467, 0.706),  # blue
    (1.0, 0.498, 0.055),  # orange
    (0.173, 0.627, 0.173),  # green
    (0.839, 0.153, 0.157),  # red
    (0.58, 0.404, 0.741),  # purple
    (0.549, 0.337, 0.294),  # brown
    (0.89, 0.467, 0.761),  # pink
    (0.09, 0.745, 0.812),  # cyan
    (0.737, 0.741, 0.133),  # olive
    (1.0, 0.85, 0.1),  # yellow
)
# Neutral board colours, chosen to contrast with every PALETTE entry.
BOARD_PALETTE: tuple[tuple[float, float, float], ...] = (
    (0.85, 0.85, 0.82),  # light grey
    (0.8, 0.7, 0.55),  # light wood
    (0.93, 0.93, 0.93),  # off-white
    (0.6, 0.62, 0.65),  # slate
)

# Generator layout: a row of three and a row of two slots, rows along y at x = +/-ROW_X.
ROW_X = 0.045
ROW3_Y = (-0.085, 0.0, 0.085)
ROW2_Y = (-0.045, 0.045)
POSITION_JITTER = 0.004
# The generator keeps at least this much board between neighbouring pockets.
MIN_SLOT_GAP = 0.004
# ...measured between pockets cut with at least this clearance, whatever their own: the 300 default kits were laid
# out with 2 mm pockets, and per-shape clearances (all smaller) leave every one of them as it was.
LAYOUT_CLEARANCE = DEFAULT_CLEARANCE
_MAX_LAYOUT_ATTEMPTS = 200


class EpisodeFileError(KitbenchError):
    """An episode file (or dict) that does not follow the schema; the message names file and field."""


# --------------------------------------------------------------------------- data classes


@dataclass(frozen=True)
class Slot:
    shape_id: int
    pos: tuple[float, float]
    yaw: float

    @property
    def pose(self) -> SlotPose:
        """(shape_id, x, y, yaw), the form board_geometry() takes."""
        return (self.shape_id, self.pos[0], self.pos[1], self.yaw)


@dataclass(frozen=True)
class BoardSpec:
    size: tuple[float, float] = BOARD_SIZE
    top: float = BOARD_TOP
    pocket_depth: float = POCKET_DEPTH
    clearance: tuple[float, ...] = SLOT_CLEARANCE  # pocket clearance per shape id (m)
    # The shapes' size against the standard shapes' (kits.shapes.shape_geometry); the board's size, top and pocket
    # depth, the clearances and the slot positions are stated at it.
    scale: float = 1.0

    @property
    def floor(self) -> float:
        """z of the pocket floors (where seated shapes' bottoms rest)."""
        return self.top - self.pocket_depth


@dataclass(frozen=True)
class Episode:
    index: int
    kit_id: int
    slots: tuple[Slot, ...]
    obj_to_place: int
    obj_in_place: tuple[int, ...]
    board_color: tuple[float, float, float]
    slot_colors: tuple[tuple[float, float, float], ...]

    @property
    def target_slot(self) -> Slot:
        """The slot the loose object belongs in."""
        return self.slots[self.obj_to_place]

    @property
    def target(self) -> tuple[int, tuple[float, float], float]:
        """(shape_id, (x, y), yaw) of the target slot."""
        s = self.target_slot
        return s.shape_id, s.pos, s.yaw

    @property
    def target_shape_id(self) -> int:
        return self.target_slot.shape_id

    @property
    def empty_slots(self) -> tuple[int, ...]:
        """Slots that start empty and are not the target: distractor pockets."""
        used = {self.obj_to_place, *self.obj_in_place}
        return tuple(i for i in range(len(self.slots)) if i not in used)

    def slot_poses(self) -> list[SlotPose]:
        return [s.pose for s in self.slots]

    def goal_pose(self, floor: float = SLOT_FLOOR) -> tuple[np.ndarray, float]:
        """Seated pose of the object to place: (shape origin xyz, yaw); the origin is on its bottom face."""
        return seated_pose(self.target_slot, floor)

    def seated_pose(self, slot_index: int, floor: float = SLOT_FLOOR) -> tuple[np.ndarray, float]:
        """Pose of a shape seated in any slot (for the obj_in_place objects)."""
        return seated_pose(self.slots[slot_index], floor)

    def to_dict(self) -> dict[str, Any]:
        return {
            "kit_id": self.kit_id,
            "slots": [{"shape_id": s.shape_id, "pos": list(s.pos), "yaw": s.yaw} for s in self.slots],
            "obj_to_place": self.obj_to_place,
            "obj_in_place": list(self.obj_in_place),
            "colors": {"board": list(self.board_color), "slots": [list(c) for c in self.slot_colors]},
        }


def seated_pose(slot: Slot, floor: float = SLOT_FLOOR) -> tuple[np.ndarray, float]:
    return np.array([slot.pos[0], slot.pos[1], floor]), float(slot.yaw)


@dataclass(frozen=True)
class EpisodeSet:
    source: str
    board: BoardSpec
    episodes: tuple[Episode, ...]

    def __len__(self) -> int:
        return len(self.episodes)

    def __getitem__(self, i: int) -> Episode:
        return self.episodes[i]

    def __iter__(self) -> Iterator[Episode]:
        return iter(self.episodes)

    def goal_pose(self, i: int) -> tuple[np.ndarray, float]:
        return self.episodes[i].goal_pose(self.board.floor)

    def board_geometry(self, i: int) -> BoardGeometry:
        """Board geometry of episode i (not cached: ~10-30 ms, callers cache per kit)."""
        b = self.board
        return board_geometry(self.episodes[i].slot_poses(), b.clearance, b.size, b.top, b.pocket_depth, b.scale)

    def scaled(self, factor: float) -> EpisodeSet:
        """The same kits `factor` times as large in every dimension: the shapes, their pockets' clearances (the
        same largest seated yaw), the slots' positions and the board; yaws unchanged."""
        factor = check_scale(factor)
        if factor == 1.0:
            return self
        b = self.board
        board = replace(
            b,
            size=(b.size[0] * factor, b.size[1] * factor),
            top=b.top * factor,
            pocket_depth=b.pocket_depth * factor,
            clearance=tuple(c * factor for c in b.clearance),
            scale=b.scale * factor,
        )
        episodes = tuple(
            replace(e, slots=tuple(replace(s, pos=(s.pos[0] * factor, s.pos[1] * factor)) for s in e.slots))
            for e in self.episodes
        )
        return EpisodeSet(source=self.source, board=board, episodes=episodes)

    def to_dict(self) -> dict[str, Any]:
        b = self.board
        return {
            "format": FORMAT,
            "version": VERSION,
            "board": {
                "size": list(b.size),
                "top": b.top,
                "pocket_depth": b.pocket_depth,
                "clearance": list(b.clearance),
                **({"scale": b.scale} if b.scale != 1.0 else {}),
            },
            "episodes": [e.to_dict() for e in self.episodes],
        }


# --------------------------------------------------------------------------- generator


def _slot_positions(rng: np.random.Generator) -> list[tuple[float, float]]:
    """Template slot centres: a row of three and a row of two; which row is far from the robot is random."""
    sign = 1.0 if rng.random() < 0.5 else -1.0
    row3 = [(sign * ROW_X, y) for y in ROW3_Y]
    row2 = [(-sign * ROW_X, y) for y in ROW2_Y]
    return row3 + row2


def _random_layout(
    rng: np.random.Generator, shapes: Sequence[int], clearance: tuple[float, ...]
) -> list[dict[str, Any]]:
    """Jittered template positions and uniform yaws, retried until the layout is valid after rounding, with pockets
    cut at `clearance` (per shape id)."""
    centres = _slot_positions(rng)
    for _ in range(_MAX_LAYOUT_ATTEMPTS):
        jitter = rng.uniform(-POSITION_JITTER, POSITION_JITTER, size=(len(shapes), 2))
        yaws = rng.uniform(-math.pi, math.pi, size=len(shapes))
        poses: list[SlotPose] = [
            (int(sid), _r(cx + jx), _r(cy + jy), _r(yaw))
            for sid, (cx, cy), (jx, jy), yaw in zip(shapes, centres, jitter, yaws, strict=True)
        ]
        polys = placed_slot_polygons(poses, clearance)
        if not layout_problems(polys, BOARD_SIZE, margin=BOARD_MARGIN, min_gap=MIN_SLOT_GAP):
            return [{"shape_id": sid, "pos": [x, y], "yaw": yaw} for sid, x, y, yaw in poses]
    raise RuntimeError(f"no valid layout for shapes {list(shapes)} after {_MAX_LAYOUT_ATTEMPTS} attempts")


def _r(x: float) -> float:
    return round(float(x), ROUND_DIGITS)


def _generate_episode(rng: np.random.Generator, index: int, clearance: tuple[float, ...]) -> dict[str, Any]:
    target = index % NUM_SHAPES
    others = rng.choice([s for s in range(NUM_SHAPES) if s != target], size=SLOTS_PER_KIT - 1, replace=False)
    shapes = [target, *(int(s) for s in others)]
    order = rng.permutation(SLOTS_PER_KIT)
    shapes = [shapes[k] for k in order]
    obj_to_place = shapes.index(target)
    slots = _random_layout(rng, shapes, clearance)
    rest = [i for i in range(SLOTS_PER_KIT) if i != obj_to_place]
    n_in_place = int(rng.integers(1, SLOTS_PER_KIT))  # 1..4: leaves 0..3 empty distractor pockets
    in_place = sorted(int(i) for i in rng.choice(rest, size=n_in_place, replace=False))
    colors = rng.choice(len(PALETTE), size=SLOTS_PER_KIT, replace=False)
    board_color = BOARD_PALETTE[int(rng.integers(len(BOARD_PALETTE)))]
    return {
        "kit_id": index,
        "slots": slots,
        "obj_to_place": obj_to_place,
        "obj_in_place": in_place,
        "colors": {"board": list(board_color), "slots": [list(PALETTE[int(c)]) for c in colors]},
    }


def generate_episodes(n: int = DEFAULT_EPISODES, seed: int = 0, clearance: Clearance = None) -> dict[str, Any]:
    """Deterministic episode set as a schema-v2 dict.

    The target shape cycles through ids 0..19 so every shape is the object to
    place n/20 times; everything else comes from one seeded numpy Generator,
    consumed in a fixed order, so (n, seed, clearance) fully determine the output.
    Pockets are cut with `clearance` (default: each shape's own, SLOT_CLEARANCE)
    and laid out as if each had at least LAYOUT_CLEARANCE.
    """
    if n < 1:
        raise KitbenchError(f"n must be >= 1, got {n}")
    clearances = pocket_clearances(clearance)
    spacing = tuple(max(c, LAYOUT_CLEARANCE) for c in clearances)
    rng = np.random.default_rng(seed)
    return {
        "format": FORMAT,
        "version": VERSION,
        "board": {
            "size": list(BOARD_SIZE),
            "top": BOARD_TOP,
            "pocket_depth": POCKET_DEPTH,
            "clearance": list(clearances),
        },
        "generator": {"function": "kitbench.kits.episodes.generate_episodes", "n": n, "seed": seed},
        "episodes": [_generate_episode(rng, i, spacing) for i in range(n)],
    }


def _compact_json(value: Any) -> str:
    return json.dumps(value, separators=(",", ":"), allow_nan=False)


def dumps_episodes(data: dict[str, Any]) -> str:
    """Compact JSON with one episode per line, so regenerated files diff readably."""
    head = {k: v for k, v in data.items() if k != "episodes"}
    lines = [_compact_json(ep) for ep in data["episodes"]]
    return _compact_json(head)[:-1] + ',"episodes":[\n' + ",\n".join(lines) + "\n]}\n"


def default_episodes_path() -> Path:
    """Source-tree location of the packaged episode file (for regeneration)."""
    return Path(__file__).resolve().parent / "data" / DEFAULT_FILE


# --------------------------------------------------------------------------- loader / validator
