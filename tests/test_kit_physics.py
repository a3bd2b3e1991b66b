"""AssemblingKits physics over every kit of the default episode file, not one kit per shape.

What PhysX does with a kit differs from kit to kit (the board around each pocket, the neighbouring pockets), so a
property that holds for one kit per shape can fail for others: the ring used to enter its pocket in 2 of its first
15 kits while passing a one-kit test, and the arrow jammed or was thrown out of 2 of its 15 (docs/kit-physics.md).

Drops follow bench/kit_drops.py: the loose shape released 1 cm above its seated pose (its bottom face level with
the board top), 30 control steps with the robot holding still.
"""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
import sapien
from sapien import physx
from shapely.geometry import MultiPoint

import kitbench  # noqa: F401
from kitbench.geometry import yaw_quat
from kitbench.kits import DEFAULT_PAD_WIDTH, NUM_SHAPES, SYMMETRY, load_episodes, shape_geometry
from kitbench.kits.clearance import MAX_MODELLED_YAW, max_seated_yaw, required_clearance
from kitbench.kits.shapes import narrowest_grasp, shape_outline
from kitbench.robots.panda import FINGER_PAD_WIDTH, MAX_GRASP_WIDTH
from kitbench.sim.actors import convex_collision_shape, cooked_vertices

TASK = "kitbench/AssemblingKits-v1"
HOLD = np.array([0, 0, 0, 0, 0, 0, 0, -1], dtype=np.float32)
DROP_STEPS = 30
# Cooked in metres, PhysX moves a shape's hull faces by up to 0.48 mm (its plane tolerance); cooked in millimetres
# they come out exact.
COOKED_HULL_TOLERANCE = 1e-6
# Reset seeds whose kits failed before the board collided as one mesh: the arrow jammed on the rim (37, 94) or was
# thrown 12 cm (154), the ring's pose turned non-finite (112).
FORMER_FAILURES = (37, 94, 112, 154)


@pytest.fixture(scope="module")
def env():
    e = gym.make(TASK, obs_mode="state_dict").unwrapped
    yield e
    e.close()


def _kits_by_target(env, shape_id: int) -> list[int]:
    return [i for i, e in enumerate(env.episodes) if e.target_shape_id == shape_id]


def _hull_error(piece: np.ndarray, material: physx.PhysxMaterial) -> float:
    """Largest distance (m) between the intended prism and the hull PhysX cooked from it, in plan and height."""
    cooked = cooked_vertices(convex_collision_shape(piece, material))
    want = MultiPoint(piece[:, :2].astype(np.float64).tolist()).convex_hull
    got = MultiPoint(cooked[:, :2].tolist()).convex_hull
    dz = max(abs(cooked[:, 2].min() - piece[:, 2].min()), abs(cooked[:, 2].max() - piece[:, 2].max()))
    return max(want.hausdorff_distance(got), float(dz))


def test_every_shape_has_a_grasp_the_panda_hand_spans():
    # ShapeGeometry.grasp_angle / grasp_width, which the planner falls back on, are computed for the default pads.
    assert DEFAULT_PAD_WIDTH == FINGER_PAD_WIDTH
    too_wide = {}
    for shape_id in range(NUM_SHAPES):
        _, width = narrowest_grasp(shape_id, pad_width=FINGER_PAD_WIDTH)
        if width > MAX_GRASP_WIDTH:
            too_wide[shape_id] = width
    assert not too_wide, f"narrowest Panda grasp wider than {MAX_GRASP_WIDTH} m: {too_wide}"


def test_cooked_hulls_keep_the_exact_geometry_of_every_shape():
    material = physx.PhysxMaterial(1.0, 1.0, 0.0)
    worst = max(
        _hull_error(piece, material)
        for shape_id in range(NUM_SHAPES)
        for piece in shape_geometry(shape_id).convex_pieces
    )
    assert worst < COOKED_HULL_TOLERANCE, worst


def test_every_board_collides_as_its_exact_surface_mesh():
    """Triangle meshes are not cooked into hulls: PhysX keeps every vertex and triangle of each default board."""
    material = physx.PhysxMaterial(1.0, 1.0, 0.0)
    episodes = load_episodes(None)
    for index in range(len(episodes)):
        vertices, faces = episodes.board_geometry(index).collision_mesh
        shape = physx.PhysxCollisionShapeTriangleMesh(
            vertices, faces.astype(np.uint32), np.ones(3, np.float32), material
        )
        got = np.asarray(shape.get_vertices(), dtype=np.float32)
        assert len(got) == len(vertices) and len(shape.get_triangles()) == len(faces), index
        assert np.array_equal(np.unique(got, axis=0), np.unique(vertices, axis=0)), index


def _release(env, kit: int, dyaw_deg: float, held: bool = False, steps: int = DROP_STEPS) -> dict:
    """Release the target of kit `kit` 1 cm above its seated pose, turned by dyaw. `held`: free only to fall (no
    turning, no sliding), 1 mm above the board top and shifted as far into the pocket as the yaw allows
    (kits/clearance.py), so that only the pocket's outline decides whether it enters."""
    env.reset(seed=0, options={"episode_index": kit})
    shift, height = (0.0, 0.0), env.episodes.board.pocket_depth
    if held:
        env.obj_body.set_locked_motion_axes([True, True, False, True, True, True])
        shift = required_clearance(shape_outline(env.shape.shape_id), math.radians(dyaw_deg))[1]
        height += 0.001
    c, s = math.cos(env.goal_rot), math.sin(env.goal_rot)
    xy = env.goal_pos[:2] + np.array([c * shift[0] - s * shift[1], s * shift[0] + c * shift[1]])
    env.obj.set_pose(sapien.Pose([*xy, env.goal_pos[2] + height], yaw_quat(env.goal_rot + math.radians(dyaw_deg))))
    info: dict = {}
    for _ in range(steps):  # on past a success, so that the shape comes to rest
        _, _, _, _, info = env.step(HOLD)
        if "physics_error" in info:
            break
    return info


@pytest.mark.parametrize("shape_id", range(NUM_SHAPES))
def test_released_one_or_two_degrees_off_a_shape_seats_in_every_kit(env, shape_id):
    kits = _kits_by_target(env, shape_id)
    assert kits, f"no default episode has shape {shape_id} as its target"
    missed = [
        (kit, dyaw, info.get("physics_error"))
        for kit in kits
        for dyaw in (1.0, -1.0, 2.0, -2.0)
        if not (info := _release(env, kit, dyaw))["success"]
    ]
    assert not missed, f"shape {shape_id} did not seat (kit, yaw offset, physics error): {missed}"


@pytest.mark.parametrize("seed", FORMER_FAILURES)
def test_the_kits_that_jammed_threw_or_diverged_now_seat(env, seed):
    env.reset(seed=seed)
    kit = env.episode_index
    for dyaw in (1.0, -1.0, 2.0, -2.0):
        info = _release(env, kit, dyaw)
        assert info["success"] and "physics_error" not in info, (seed, kit, dyaw, info)


@pytest.mark.parametrize("shape_id", [i for i in range(NUM_SHAPES) if SYMMETRY[i] > 0])
def test_held_at_the_tolerance_no_shape_reaches_its_pocket_in_any_kit(env, shape_id):
    """The 4-degree rule and the pocket agree: turned 4 degrees, at the shift that fits it best, no shape ends
    in_slot (the pockets stop them from 3.5 degrees on: kits/clearance.py)."""
    entered = [
        (kit, dyaw)
        for kit in _kits_by_target(env, shape_id)
        for dyaw in (4.0, -4.0)
        if _release(env, kit, dyaw, held=True, steps=20)["in_slot"]
    ]
    assert not entered, f"shape {shape_id} reached its pocket 4 degrees off (kit, yaw offset): {entered}"


@pytest.mark.parametrize("shape_id", [i for i in range(NUM_SHAPES) if SYMMETRY[i] > 0])
def test_simulated_limit_matches_the_computed_one(env, shape_id):
    """Held half a degree inside the computed largest yaw the shape enters its pocket, half a degree beyond it does
    not, turning either way (bench/kit_drops.py bisects: PhysX's limit lies within 0.1 degree below)."""
    kit = _kits_by_target(env, shape_id)[0]
    limit = min(MAX_MODELLED_YAW, SYMMETRY[shape_id] / 2)
    clearance = env.episodes.board.clearance[shape_id]
    for sense in (1.0, -1.0):
        computed = math.degrees(max_seated_yaw(shape_outline(shape_id), clearance, limit, sense))
        assert _release(env, kit, sense * (computed - 0.5), held=True, steps=20)["in_slot"], (sense, computed)
        assert not _release(env, kit, sense * (computed + 0.5), held=True, steps=20)["in_slot"], (sense, computed)
