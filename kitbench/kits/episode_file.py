"""Reading an AssemblingKits episode file: parsed, checked field by field against the schema
(`kitbench.kits.episodes`, version 2 or 1) and built into an `EpisodeSet`; a bad file is one line naming the field
and what is wrong with it (`EpisodeFileError`); and the packaged file written anew from the generator:

    python -m kitbench.kits.episode_file          # regenerate the packaged file
"""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Sequence
from importlib import resources
from pathlib import Path
from typing import Any, NoReturn

from kitbench.kits.board import layout_problems, placed_slot_polygons
from kitbench.kits.clearance import DEFAULT_CLEARANCE
from kitbench.kits.episodes import (
    DEFAULT_FILE,
    FORMAT,
    READABLE_VERSIONS,
    BoardSpec,
    Episode,
    EpisodeFileError,
    EpisodeSet,
    Slot,
    default_episodes_path,
    dumps_episodes,
    generate_episodes,
)
from kitbench.kits.shapes import NUM_SHAPES


class _Checker:
    """Type checks that raise EpisodeFileError naming the source and the JSON path."""

    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, path: str, msg: str) -> NoReturn:
        raise EpisodeFileError(f"{self.source}: {path}: {msg}" if path else f"{self.source}: {msg}")

    def field(self, obj: dict[str, Any], key: str, path: str) -> Any:
        if key not in obj:
            self.fail(path or "(top level)", f"missing field '{key}'")
        return obj[key]

    def obj(self, value: Any, path: str) -> dict[str, Any]:
        if not isinstance(value, dict):
            self.fail(path, f"expected an object, got {_describe(value)}")
        return value

    def array(self, value: Any, path: str, length: int | None = None, min_len: int = 0) -> list[Any]:
        if not isinstance(value, list):
            self.fail(path, f"expected a list, got {_describe(value)}")
        if length is not None and len(value) != length:
            self.fail(path, f"expected {length} entries, got {len(value)}")
        if len(value) < min_len:
            self.fail(path, f"expected at least {min_len} {'entry' if min_len == 1 else 'entries'}, got {len(value)}")
        return value

    def integer(self, value: Any, path: str, lo: int | None = None) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            self.fail(path, f"expected an integer, got {_describe(value)}")
        if lo is not None and value < lo:
            self.fail(path, f"expected an integer >= {lo}, got {value}")
        return value

    def num(
        self, value: Any, path: str, lo: float | None = None, hi: float | None = None, positive: bool = False
    ) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(path, f"expected a number, got {_describe(value)}")
        if not math.isfinite(value):
            self.fail(path, f"expected a finite number, got {value}")
        if positive and not value > 0:
            self.fail(path, f"expected a positive number, got {value}")
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            self.fail(path, f"{value} outside [{lo}, {hi}]")
        return float(value)

    def vec(
        self, value: Any, path: str, n: int, lo: float | None = None, hi: float | None = None, positive: bool = False
    ) -> tuple[float, ...]:
        items = self.array(value, path, length=n)
        return tuple(self.num(v, f"{path}[{i}]", lo=lo, hi=hi, positive=positive) for i, v in enumerate(items))

    def rgb(self, value: Any, path: str) -> tuple[float, float, float]:
        r, g, b = self.vec(value, path, 3, lo=0.0, hi=1.0)
        return r, g, b


def _describe(value: Any) -> str:
    text = json.dumps(value) if not isinstance(value, float) or math.isfinite(value) else repr(value)
    if len(text) > 40:
        text = text[:37] + "..."
    return f"{text} ({type(value).__name__})"


def _check_board(c: _Checker, data: dict[str, Any], version: int) -> BoardSpec:
    board = c.obj(c.field(data, "board", ""), "board")
    size = c.vec(c.field(board, "size", "board"), "board.size", 2, positive=True)
    top = c.num(c.field(board, "top", "board"), "board.top", positive=True)
    depth = c.num(c.field(board, "pocket_depth", "board"), "board.pocket_depth", positive=True)
    if depth >= top:
        c.fail("board.pocket_depth", f"pocket depth {depth} must be less than the board top {top}")
    if version == 1:  # one optional clearance for every pocket
        uniform = c.num(board["clearance"], "board.clearance", lo=0.0) if "clearance" in board else DEFAULT_CLEARANCE
        clearance = (uniform,) * NUM_SHAPES
    else:  # required: one for every pocket, or one per shape id
        value = c.field(board, "clearance", "board")
        if isinstance(value, list):
            clearance = c.vec(value, "board.clearance", NUM_SHAPES, lo=0.0)
        else:
            clearance = (c.num(value, "board.clearance", lo=0.0),) * NUM_SHAPES
    # optional: the shapes' size against the standard ones (a kit built smaller for a smaller hand)
    scale = c.num(board["scale"], "board.scale", hi=2.0, positive=True) if "scale" in board else 1.0
    return BoardSpec(size=(size[0], size[1]), top=top, pocket_depth=depth, clearance=clearance, scale=scale)


def _check_slots(c: _Checker, ep: dict[str, Any], path: str) -> tuple[Slot, ...]:
    raw = c.array(c.field(ep, "slots", path), f"{path}.slots", min_len=1)
    slots: list[Slot] = []
    seen: dict[int, int] = {}
    for j, s in enumerate(raw):
        sp = f"{path}.slots[{j}]"
        c.obj(s, sp)
        sid = c.integer(c.field(s, "shape_id", sp), f"{sp}.shape_id")
        if not 0 <= sid < NUM_SHAPES:
            c.fail(f"{sp}.shape_id", f"unknown shape id {sid} (valid: 0..{NUM_SHAPES - 1})")
        if sid in seen:
            c.fail(f"{sp}.shape_id", f"duplicate shape id {sid} (also in slots[{seen[sid]}])")
        seen[sid] = j
        pos = c.vec(c.field(s, "pos", sp), f"{sp}.pos", 2)
        yaw = c.num(c.field(s, "yaw", sp), f"{sp}.yaw")
        slots.append(Slot(shape_id=sid, pos=(pos[0], pos[1]), yaw=yaw))
    return tuple(slots)


def _check_indices(c: _Checker, ep: dict[str, Any], path: str, n_slots: int) -> tuple[int, tuple[int, ...]]:
    span = f"(kit has {n_slots} slots: 0..{n_slots - 1})"
    target = c.integer(c.field(ep, "obj_to_place", path), f"{path}.obj_to_place")
    if not 0 <= target < n_slots:
        c.fail(f"{path}.obj_to_place", f"slot index {target} out of range {span}")
    in_place = c.array(c.field(ep, "obj_in_place", path), f"{path}.obj_in_place")
    seen: set[int] = set()
    for k, v in enumerate(in_place):
        ip = f"{path}.obj_in_place[{k}]"
        c.integer(v, ip)
        if not 0 <= v < n_slots:
            c.fail(ip, f"slot index {v} out of range {span}")
        if v == target:
            c.fail(ip, f"slot {v} is obj_to_place; it cannot also start in place")
        if v in seen:
            c.fail(ip, f"slot {v} listed twice")
        seen.add(v)
    return target, tuple(in_place)


def _check_colors(
    c: _Checker, ep: dict[str, Any], path: str, n_slots: int
) -> tuple[tuple[float, float, float], tuple[tuple[float, float, float], ...]]:
    cp = f"{path}.colors"
    colors = c.obj(c.field(ep, "colors", path), cp)
    board = c.rgb(c.field(colors, "board", cp), f"{cp}.board")
    raw = c.array(c.field(colors, "slots", cp), f"{cp}.slots")
    if len(raw) != n_slots:
        c.fail(f"{cp}.slots", f"expected one colour per slot ({n_slots}), got {len(raw)}")
    slot_colors = tuple(c.rgb(v, f"{cp}.slots[{k}]") for k, v in enumerate(raw))
    return board, slot_colors


def _check_layout(c: _Checker, slots: Sequence[Slot], path: str, board: BoardSpec) -> None:
    polys = placed_slot_polygons([s.pose for s in slots], board.clearance, board.scale)
    problems = layout_problems(polys, board.size)
    if problems:
        j, msg = problems[0]
        c.fail(f"{path}.slots[{j}]", msg)


def _check_episode(c: _Checker, ep: Any, i: int, board: BoardSpec) -> Episode:
    path = f"episodes[{i}]"
    ep = c.obj(ep, path)
    kit_id = c.integer(c.field(ep, "kit_id", path), f"{path}.kit_id", lo=0)
    slots = _check_slots(c, ep, path)
    target, in_place = _check_indices(c, ep, path, len(slots))
    board_color, slot_colors = _check_colors(c, ep, path, len(slots))
    _check_layout(c, slots, path, board)
    return Episode(
        index=i,
        kit_id=kit_id,
        slots=slots,
        obj_to_place=target,
        obj_in_place=in_place,
        board_color=board_color,
        slot_colors=slot_colors,
    )


def validate_episodes(data: Any, source: str = "<episodes>") -> EpisodeSet:
    """Check a parsed episode document against schema v2 (or v1) and build the EpisodeSet."""
    c = _Checker(source)
    data = c.obj(data, "(top level)")
    fmt = c.field(data, "format", "")
    if fmt != FORMAT:
        c.fail("format", f"expected {FORMAT!r}, got {_describe(fmt)}")
    version = c.field(data, "version", "")
    if isinstance(version, bool) or version not in READABLE_VERSIONS:
        supported = ", ".join(str(v) for v in READABLE_VERSIONS)
        c.fail("version", f"unsupported version {_describe(version)} (supported: {supported})")
    board = _check_board(c, data, version)
    raw = c.array(c.field(data, "episodes", ""), "episodes", min_len=1)
    episodes = tuple(_check_episode(c, ep, i, board) for i, ep in enumerate(raw))
    return EpisodeSet(source=source, board=board, episodes=episodes)


def _read_text(path: str | Path | None) -> tuple[str, str]:
    if path is None:
        res = resources.files("kitbench.kits").joinpath("data", DEFAULT_FILE)
        return str(res), res.read_text(encoding="utf-8")
    p = Path(path)
    try:
        return str(p), p.read_text(encoding="utf-8")
    except OSError as e:
        raise EpisodeFileError(f"{p}: cannot read episode file: {e.strerror or e}") from e
    except UnicodeDecodeError as e:
        raise EpisodeFileError(f"{p}: not UTF-8 text: {e}") from e


def load_episodes(path: str | Path | None = None) -> EpisodeSet:
    """Load and validate an episode file (default: the one packaged with kitbench)."""
    source, text = _read_text(path)
    try:
        data = json.loads(text)
    except json.JSONDecodeError as e:
        raise EpisodeFileError(f"{source}: line {e.lineno} col {e.colno}: malformed JSON: {e.msg}") from e
    return validate_episodes(data, source=source)


def write_default_episodes(path: str | Path | None = None) -> Path:
    """Regenerate the packaged episode file with the default arguments."""
    path = Path(path) if path is not None else default_episodes_path()
    data = generate_episodes()
    validate_episodes(data, source=str(path))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(dumps_episodes(data), encoding="utf-8")
    return path


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    path = write_default_episodes(argv[0] if argv else None)
    eps = load_episodes(path)
    print(f"wrote {len(eps)} episodes to {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
