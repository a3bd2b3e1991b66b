"""AssemblingKits episode files: generator determinism, the committed file, and validation errors."""

from __future__ import annotations

import copy
import json
from collections import Counter
from importlib import resources

import numpy as np
import pytest

from kitbench.kits.board import BOARD_MARGIN, SLOT_FLOOR, layout_problems, placed_slot_polygons
from kitbench.kits.clearance import SLOT_CLEARANCE
from kitbench.kits.episode_file import load_episodes, validate_episodes
from kitbench.kits.episodes import (
    FORMAT,
    MIN_SLOT_GAP,
    PALETTE,
    SLOTS_PER_KIT,
    VERSION,
    EpisodeFileError,
    dumps_episodes,
    generate_episodes,
)
from kitbench.kits.shapes import NUM_SHAPES, place, slot_outline


@pytest.fixture(scope="module")
def default_data() -> dict:
    return generate_episodes()


@pytest.fixture(scope="module")
def packaged_text() -> str:
    return resources.files("kitbench.kits").joinpath("data", "episodes.json").read_text(encoding="utf-8")


# --------------------------------------------------------------------------- generator


def test_generator_is_deterministic():
    a, b = generate_episodes(40, seed=3), generate_episodes(40, seed=3)
    assert a == b
    assert json.dumps(a) == json.dumps(b)
    assert generate_episodes(40, seed=4)["episodes"] != a["episodes"]
    # a shorter run is a prefix of a longer one: episode i never depends on n
    assert generate_episodes(10, seed=3)["episodes"] == a["episodes"][:10]


def test_committed_file_is_the_generator_output(default_data, packaged_text):
    assert json.loads(packaged_text) == default_data, "regenerate with: python -m kitbench.kits.episode_file"
    assert packaged_text == dumps_episodes(default_data)
    assert len(packaged_text) < 200_000


def test_every_shape_is_a_target_often(default_data):
    counts = Counter(ep["slots"][ep["obj_to_place"]]["shape_id"] for ep in default_data["episodes"])
    assert sorted(counts) == list(range(NUM_SHAPES))
    assert min(counts.values()) >= 10
    # every shape also appears as a non-target (in place or distractor)
    others = Counter(s["shape_id"] for ep in default_data["episodes"] for s in ep["slots"])
    assert all(others[s] > counts[s] for s in range(NUM_SHAPES))


def test_generated_kits_follow_the_layout_rules(default_data):
    board = default_data["board"]
    for ep in default_data["episodes"]:
        slots = ep["slots"]
        assert len(slots) == SLOTS_PER_KIT
        assert len({s["shape_id"] for s in slots}) == SLOTS_PER_KIT
        polys = placed_slot_polygons([(s["shape_id"], *s["pos"], s["yaw"]) for s in slots], board["clearance"])
        assert layout_problems(polys, board["size"], margin=BOARD_MARGIN, min_gap=MIN_SLOT_GAP) == []
        # a row of three and a row of two, rows at different x
        xs = sorted(np.sign(s["pos"][0]) for s in slots)
        assert Counter(xs) in (Counter({-1: 3, 1: 2}), Counter({-1: 2, 1: 3}))
        assert ep["obj_to_place"] not in ep["obj_in_place"]
        assert 1 <= len(ep["obj_in_place"]) <= 4
        assert all(tuple(c) in PALETTE for c in ep["colors"]["slots"])
        assert len({tuple(c) for c in ep["colors"]["slots"]}) == SLOTS_PER_KIT
        for s in slots:  # rounded to 1e-5 so the file stays small and round-trips exactly
            assert all(round(v, 5) == v for v in [*s["pos"], s["yaw"]])
    yaws = np.array([s["yaw"] for ep in default_data["episodes"] for s in ep["slots"]])
    assert yaws.min() < -3.0 and yaws.max() > 3.0


# --------------------------------------------------------------------------- loader


def test_load_packaged_file():
    eps = load_episodes()
    assert len(eps) == 300 and eps.source.endswith("episodes.json")
    assert eps.board.size == (0.20, 0.28) and eps.board.floor == pytest.approx(SLOT_FLOOR)
    ep = eps[7]
    shape_id, pos, yaw = ep.target
    assert shape_id == ep.target_shape_id == 7  # targets cycle through the shape ids
    assert ep.target_slot.shape_id == shape_id
    xyz, goal_yaw = ep.goal_pose()
    np.testing.assert_allclose(xyz, [pos[0], pos[1], 0.01])
    assert goal_yaw == yaw
    assert eps.goal_pose(7)[1] == yaw
    assert set(ep.empty_slots) | set(ep.obj_in_place) | {ep.obj_to_place} == set(range(len(ep.slots)))
    assert ep.slot_poses()[ep.obj_to_place] == (shape_id, pos[0], pos[1], yaw)
    b = eps.board_geometry(7)
    assert len(b.slot_polygons) == len(ep.slots)


def test_the_packaged_kits_are_those_laid_out_with_two_millimetre_pockets(default_data):
    """Seeds keep their meaning: the per-shape pockets (all smaller) are cut into the kits laid out before, when every
    pocket had 2 mm (format version 1): same slots, targets, seated shapes and colours."""
    assert default_data["board"]["clearance"] == list(SLOT_CLEARANCE)
    assert generate_episodes(clearance=0.002)["episodes"] == default_data["episodes"]


def test_version_1_files_keep_one_clearance_for_every_pocket(small_valid, tmp_path):
    data = copy.deepcopy(small_valid)
    data["version"] = 1
    data["board"]["clearance"] = 0.003
    path = tmp_path / "v1.json"
    path.write_text(json.dumps(data))
    assert load_episodes(path).board.clearance == (0.003,) * NUM_SHAPES
    del data["board"]["clearance"]
    path.write_text(json.dumps(data))
    eps = load_episodes(path)
    assert eps.board.clearance == (0.002,) * NUM_SHAPES  # version 1's default
    board = eps.board_geometry(0)
    sid, x, y, yaw = eps[0].slot_poses()[0]
    assert board.slot_polygons[0].equals_exact(place(slot_outline(sid, 0.002), x, y, yaw), 1e-12)


def test_version_2_files_may_give_one_clearance_for_every_pocket(small_valid):
    data = copy.deepcopy(small_valid)
    data["board"]["clearance"] = 0.0025
    assert validate_episodes(data).board.clearance == (0.0025,) * NUM_SHAPES
    assert validate_episodes(small_valid).board.clearance == SLOT_CLEARANCE


def test_round_trip(tmp_path, default_data):
    small = generate_episodes(5, seed=1)
    path = tmp_path / "kits.json"
    path.write_text(json.dumps(small))
    eps = load_episodes(str(path))
    out = eps.to_dict()
    assert out["episodes"] == small["episodes"] and out["board"] == small["board"]
    assert validate_episodes(out).to_dict() == out


# --------------------------------------------------------------------------- validation errors


def _set(path, value):
    """Mutation setting data[path...] = value (path: keys/indices)."""

    def mutate(d):
        target = d
        for key in path[:-1]:
            target = target[key]
        target[path[-1]] = value

    return mutate


def _delete(path):
    def mutate(d):
        target = d
        for key in path[:-1]:
            target = target[key]
        del target[path[-1]]

    return mutate


def _copy_pos(src, dst):
    def mutate(d):
        slots = d["episodes"][0]["slots"]
        slots[dst]["pos"] = list(slots[src]["pos"])

    return mutate


def _duplicate_shape(d):
    slots = d["episodes"][0]["slots"]
    slots[3]["shape_id"] = slots[1]["shape_id"]


def _target_in_place(d):
    d["episodes"][0].update(obj_to_place=0, obj_in_place=[0])


def _in_place_twice(d):
    d["episodes"][0].update(obj_to_place=0, obj_in_place=[1, 1])


E0 = ("episodes", 0)
BAD_CASES = {
    "wrong_format": (_set(("format",), "maniskill/kits"), "format: expected 'kitbench/assembling-kits-episodes'"),
    "wrong_version": (_set(("version",), 3), "version: unsupported version 3 (int) (supported: 1, 2)"),
    "version_as_string": (_set(("version",), "1"), "version: unsupported version"),
    "missing_clearance": (_delete(("board", "clearance")), "board: missing field 'clearance'"),
    "clearance_per_shape_count": (
        _set(("board", "clearance"), [0.001, 0.002]),
        "board.clearance: expected 20 entries, got 2",
    ),
    "clearance_negative": (_set(("board", "clearance", 4), -0.001), "board.clearance[4]: -0.001 outside [0.0,"),
    "clearance_v1_list": (
        lambda d: d.update(version=1),
        "board.clearance: expected a number, got [",
    ),
    "missing_episodes": (_delete(("episodes",)), "missing field 'episodes'"),
    "empty_episodes": (_set(("episodes",), []), "episodes: expected at least 1 entry"),
    "missing_board": (_delete(("board",)), "missing field 'board'"),
    "negative_board_size": (_set(("board", "size", 0), -0.2), "board.size[0]: expected a positive number"),
    "deep_pocket": (_set(("board", "pocket_depth"), 0.03), "board.pocket_depth: pocket depth 0.03 must be less"),
    "episode_not_object": (_set(("episodes", 1), [1, 2]), "episodes[1]: expected an object"),
    "missing_kit_id": (_delete((*E0, "kit_id")), "episodes[0]: missing field 'kit_id'"),
    "bool_kit_id": (_set((*E0, "kit_id"), True), "episodes[0].kit_id: expected an integer, got true (bool)"),
    "missing_yaw": (_delete(("episodes", 1, "slots", 2, "yaw")), "episodes[1].slots[2]: missing field 'yaw'"),
    "string_shape_id": (
        _set((*E0, "slots", 0, "shape_id"), "3"),
        'episodes[0].slots[0].shape_id: expected an integer, got "3" (str)',
    ),
    "unknown_shape_id": (
        _set(("episodes", 2, "slots", 3, "shape_id"), 25),
        "episodes[2].slots[3].shape_id: unknown shape id 25 (valid: 0..19)",
    ),
    "negative_shape_id": (
        _set((*E0, "slots", 1, "shape_id"), -1),
        "episodes[0].slots[1].shape_id: unknown shape id -1",
    ),
    "duplicate_shape_id": (_duplicate_shape, "episodes[0].slots[3].shape_id: duplicate shape id"),
    "pos_arity": (_set((*E0, "slots", 1, "pos"), [0.0, 0.0, 0.0]), "episodes[0].slots[1].pos: expected 2 entries"),
    "pos_type": (_set((*E0, "slots", 1, "pos", 0), "0.1"), "episodes[0].slots[1].pos[0]: expected a number"),
    "nan_yaw": (_set((*E0, "slots", 4, "yaw"), float("nan")), "episodes[0].slots[4].yaw: expected a finite number"),
    "slots_empty": (_set((*E0, "slots"), []), "episodes[0].slots: expected at least 1 entry"),
    "target_out_of_range": (
        _set(("episodes", 1, "obj_to_place"), 5),
        "episodes[1].obj_to_place: slot index 5 out of range",
    ),
    "target_negative": (
        _set(("episodes", 1, "obj_to_place"), -1),
        "episodes[1].obj_to_place: slot index -1 out of range",
    ),
    "target_float": (_set(("episodes", 1, "obj_to_place"), 1.0), "episodes[1].obj_to_place: expected an integer"),
    "in_place_not_list": (_set((*E0, "obj_in_place"), 3), "episodes[0].obj_in_place: expected a list"),
    "in_place_out_of_range": (
        _set((*E0, "obj_in_place"), [7]),
        "episodes[0].obj_in_place[0]: slot index 7 out of range",
    ),
    "in_place_has_target": (_target_in_place, "episodes[0].obj_in_place[0]: slot 0 is obj_to_place"),
    "in_place_duplicate": (_in_place_twice, "episodes[0].obj_in_place[1]: slot 1 listed twice"),
    "overlapping_slots": (_copy_pos(0, 1), "episodes[0].slots[1]: slot outline overlaps slot 0"),
    "slot_outside_board": (
        _set((*E0, "slots", 2, "pos"), [0.5, 0.0]),
        "episodes[0].slots[2]: slot outline extends outside the board",
    ),
    "slot_on_board_edge": (
        _set((*E0, "slots", 2, "pos"), [0.095, 0.0]),
        "episodes[0].slots[2]: slot outline extends outside",
    ),
    "missing_colors": (_delete((*E0, "colors")), "episodes[0]: missing field 'colors'"),
    "board_color_arity": (
        _set((*E0, "colors", "board"), [1.0, 0.5]),
        "episodes[0].colors.board: expected 3 entries, got 2",
    ),
    "slot_color_range": (
        _set((*E0, "colors", "slots", 2, 1), 1.5),
        "episodes[0].colors.slots[2][1]: 1.5 outside [0.0, 1.0]",
    ),
    "slot_color_negative": (
        _set((*E0, "colors", "slots", 0, 0), -0.1),
        "episodes[0].colors.slots[0][0]: -0.1 outside",
    ),
    "slot_color_count": (
        _delete((*E0, "colors", "slots", 4)),
        "episodes[0].colors.slots: expected one colour per slot (5), got 4",
    ),
}


@pytest.fixture(scope="module")
def small_valid() -> dict:
    return generate_episodes(3, seed=0)


@pytest.mark.parametrize("case", sorted(BAD_CASES))
def test_bad_file_names_file_and_field(case, small_valid, tmp_path):
    mutate, expected = BAD_CASES[case]
    data = copy.deepcopy(small_valid)
    mutate(data)
    path = tmp_path / "episodes.json"
    path.write_text(json.dumps(data))  # allow_nan: NaN is written as the (non-standard) NaN literal
    with pytest.raises(EpisodeFileError) as e:
        load_episodes(path)
    msg = str(e.value)
    assert msg.startswith(f"{path}: "), msg
    assert expected in msg, msg
    assert isinstance(e.value, ValueError)


def test_unmutated_small_set_is_valid(small_valid, tmp_path):
    path = tmp_path / "episodes.json"
    path.write_text(json.dumps(small_valid))
    assert len(load_episodes(path)) == 3


@pytest.mark.parametrize(
    "text, expected",
    [
        ('{"format": "kitbench/assembling-kits-episodes",\n  "version": 1,\n  "board": {', "line 3 col"),
        ("", "line 1 col 1: malformed JSON"),
        ("[1, 2, 3]", "(top level): expected an object"),
        ('{"version": 1}', "(top level): missing field 'format'"),
    ],
)
def test_malformed_documents(tmp_path, text, expected):
    path = tmp_path / "broken.json"
    path.write_text(text)
    with pytest.raises(EpisodeFileError) as e:
        load_episodes(path)
    assert str(e.value).startswith(f"{path}: ") and expected in str(e.value)


def test_missing_file(tmp_path):
    with pytest.raises(EpisodeFileError, match="cannot read episode file"):
        load_episodes(tmp_path / "nope.json")


def test_unknown_optional_fields_are_ignored(small_valid):
    data = copy.deepcopy(small_valid)
    data["note"] = "hand-edited"
    data["episodes"][0]["comment"] = "extra"
    assert len(validate_episodes(data, source="x")) == 3
    assert FORMAT == data["format"] and VERSION == 2
