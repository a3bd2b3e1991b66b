"""AssemblingKits-v1: pick the misplaced shape and insert it into its slot in the kit.

Every asset is generated (kitbench.kits): a kit board with pockets cut to the shapes' outlines plus a clearance,
static shapes already seated in some pockets, and one loose shape to insert. Kit configurations come from a
versioned JSON episode file (the packaged default or the user's own, `episode_file=`).

Success = pos_correct and rot_correct and in_slot:
- pos_correct: the shape's origin within 2 cm (in xy) of its seated position;
- rot_correct: yaw error modulo the shape's rotational symmetry below 4 degrees (always true for a disc or
  ring); yaw is read from the shape's x axis projected on the table, not from Euler angles;
- in_slot: the shape's bottom face within 3 mm of the pocket floor.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass
from functools import cached_property, lru_cache
from pathlib import Path

import numpy as np
import sapien
from sapien import physx
from shapely.geometry import box as shapely_box

from kitbench.envs.grasp import GraspHistory
from kitbench.envs.observations import pose7
from kitbench.envs.tabletop import TabletopEnv
from kitbench.errors import KitbenchError
from kitbench.geometry import planar_yaw, quat_to_matrix, yaw_quat
from kitbench.kits import BOARD_SIZE, NUM_SHAPES, Episode, EpisodeSet, load_episodes, place, shape_geometry
from kitbench.registration import register_env
from kitbench.sim.actors import build_convex_actor, build_static_mesh_actor
from kitbench.sim.cameras import OBSERVATION_SIZE, CameraSpec, view

POS_TOLERANCE = 0.02  # m
ROT_TOLERANCE = math.radians(4.0)
IN_SLOT_TOLERANCE = 0.003  # m
SPAWN_X = (-0.1, 0.1)
SPAWN_Y = (-0.182, 0.182)


@dataclass(frozen=True)
class KitVariant:
    """One robot's build of the task: its kits' size (`EpisodeSet.scaled`: every dimension of the shapes, pockets
    and board, and the slots' positions; yaws and the success criteria unchanged) and where its loose shape spawns."""

    scale: float = 1.0
    spawn_x: tuple[float, float] = SPAWN_X
    spawn_y: tuple[float, float] = SPAWN_Y


# The SO-101's jaw spans ~5 cm: at 0.7 scale no shape needs more than 3 cm across its grasp, and the lower kit
# lets its wrist point straight down; its shape spawns where a downward jaw reaches the table (docs/robots.md).
ROBOT_VARIANTS = {"so101": KitVariant(scale=0.7, spawn_x=(-0.07, 0.03), spawn_y=(-0.15, 0.15))}
SPAWN_MARGIN = 0.004  # m kept between a spawned shape and any pocket or the board edge
SHAPE_DENSITY = 600.0  # kg/m^3, a plastic-like block of 12-27 g
# PhysX pairs two materials at the lower friction. At 0.5 a shape dropped 10 degrees off its slot yaw slides and
# turns itself into the pocket; at 1.0 most stay out, as a real block on a wooden board does (with 2 mm pockets 30
# of 270 such drops still tipped in and turned themselves straight, most of them the pointed kite; with each
# shape's own, narrower pocket none of 540 does: docs/kit-physics.md).
SHAPE_FRICTION = 1.0
BOARD_FRICTION = 1.0
MAX_DENSE_REWARD = 7.0
# Scales of the policy state's `*_fine` fields (see AssemblingKitsEnv.environment_state_keys).
FINE_GRASP_SCALE = 0.01  # m
FINE_INSERT_SCALE = 0.003  # m
FINE_TURN_SCALE = math.radians(2.0)
BOARD_CACHE_SIZE = 32
# Contact offset (m) of the kit's board, seated shapes and loose shape, instead of the scene's 2 cm. PhysX's
# persistent contact manifold reports phantom penetrations of 18-20 mm between a shape's few-millimetre pieces and
# the pocket walls once a pair's contact distance (the sum of both offsets) reaches a few piece widths: at 2 cm a
# ring released square over its pocket went in, every time, in only 2 of its 15 default kits. At 3 mm per shape
# (6 mm per pair, still above what a held shape moves in one substep) every default kit's target drops in
# (docs/kit-physics.md).
KIT_CONTACT_OFFSET = 0.003
NEAR_SLOT = 0.05  # m: a shape this close to its goal was brought to the kit, whatever else went wrong


def folded_yaw(yaw: float, symmetry: float) -> np.ndarray:
    """[cos, sin] of `yaw` times the shape's order of symmetry: equal for every yaw equivalent under it, and
    continuous in it ([1, 0] for a disc or ring, which any yaw fits)."""
    if symmetry <= 0:
        return np.array([1.0, 0.0], dtype=np.float32)
    k = 2 * math.pi / symmetry
    return np.array([math.cos(k * yaw), math.sin(k * yaw)], dtype=np.float32)


def signed_yaw_error(yaw: float, goal_yaw: float, symmetry: float) -> float:
    """Signed turn (rad) taking `yaw` to the nearest yaw equivalent to `goal_yaw`: within +-symmetry/2."""
    if symmetry <= 0:  # any rotation is equivalent (disc, ring)
        return 0.0
    return float((goal_yaw - yaw + symmetry / 2) % symmetry - symmetry / 2)


def yaw_error(yaw: float, goal_yaw: float, symmetry: float) -> float:
    """Smallest rotation (rad) taking `yaw` to a yaw equivalent to `goal_yaw` under the shape's symmetry."""
    return abs(signed_yaw_error(yaw, goal_yaw, symmetry))


@lru_cache(maxsize=8)
def _load(path: str | None, scale: float = 1.0) -> EpisodeSet:
    return load_episodes(path) if scale == 1.0 else _load(path).scaled(scale)


@register_env("AssemblingKits-v1", max_episode_steps=200)
class AssemblingKitsEnv(TabletopEnv):
    """Insert a misplaced shape into its slot in a kit (200 control steps, robot with a wrist camera)."""

    supported_robots = ("panda_wristcam", "so101")
    max_dense_reward = MAX_DENSE_REWARD
    default_qpos_noise = 0.02
    # What the expert's motion depends on, each in a form a policy can learn from
    # (measured: docs/studies/assembling-kits-state.md).
    environment_state_keys = (
        "obj_pose",
        "obj_yaw_sym",  # folded by the shape's symmetry, as the grasp and the insertion are
        "tcp_to_obj_pos",
        "goal_xy",  # not the goal's height: a constant, which normalising by its rounding-noise std would blow up
        "goal_yaw",  # yaws as cos/sin: no wrap-around
        "goal_yaw_sym",
        "obj_to_goal_pos",
        "shape_onehot",  # one-hot: the grasp, opening and symmetry are per shape
        "tcp_yaw",  # this and the next two: the turns an end-effector delta action regulates
        "tcp_to_obj_yaw",  # folded by two: the fingers close the same way at yaw and yaw + pi
        "obj_to_goal_yaw",
        "tcp_to_obj_fine",  # the grasp's and the insertion's errors on the scale they are corrected at
        "obj_to_goal_fine",
    )
    success_criteria = ("pos_correct", "rot_correct", "in_slot")
    failure_categories = ("never_grasped", "dropped", "released", "not_transported", "misaligned", "not_inserted")
    report_groups = ("shape_id", "shape")
    expert = "kitbench.planning.assembling_kits:AssemblingKitsPlanner"
    sensor_cameras = (CameraSpec.looking_at("base_camera", [0.2, 0, 0.4], [0, 0, 0], *OBSERVATION_SIZE, math.pi / 2),)
    # "board": the base camera in front of the board, lower and nearer than ManiSkill's (the task's base_camera),
    # framing the board and the loose shape's spawn area: at 64x64 a carried shape covers 28 pixels (7 in
    # ManiSkill's framing) and the slot is clear of the arm in 95% of the carry's frames (64%); bench/camera_view.py
    camera_views = {"board": {"base_camera": view([0.32, 0.0, 0.42], [-0.04, 0.0, 0.0], math.radians(50))}}  # noqa: RUF012

    def __init__(self, *args, episode_file: str | Path | None = None, **kwargs):
        self._episode_file = str(episode_file) if episode_file is not None else None
        self.episode: Episode  # chosen by every reset (the first runs in TabletopEnv.__init__)
        self.episode_index = -1
        self._boards: OrderedDict = OrderedDict()  # episode index -> BoardGeometry, least recently used last
        super().__init__(*args, **kwargs)

    @classmethod
    def variant_description(cls, robot_uid: str) -> str | None:
        variant = ROBOT_VARIANTS.get(robot_uid)
        if variant is None:
            return None
        size = " x ".join(f"{variant.scale * s * 100:g}" for s in BOARD_SIZE)
        x, y = variant.spawn_x, variant.spawn_y
        return (
            f"every kit at {variant.scale:g} scale (the shapes, their pockets and clearances, the slots' positions and "
            f"the board, {size} cm); the loose shape within x {x[0]:g}..{x[1]:g} m and y {y[0]:g}..{y[1]:g} m; the "
            "same success test"
        )

    @property
    def kit_variant(self) -> KitVariant:
        """This robot's build of the task (`ROBOT_VARIANTS`; the standard one for the Panda)."""
        return ROBOT_VARIANTS.get(self.robot_uid, KitVariant())

    @cached_property
    def episodes(self) -> EpisodeSet:
        """The episode file's kits, at this robot's variant's scale."""
        return _load(self._episode_file, self.kit_variant.scale)

    def task_description(self) -> str:
        name = self.shape.name.replace("_", " ")
        return f"Pick up the loose {name} and insert it into its matching slot in the kit."

    def episode_config(self) -> dict:
        """`kit_episode` indexes the episode file; `kit_id` is the file's own id for that kit."""
        return {
            "kit_id": int(self.episode.kit_id),
            "kit_episode": int(self.episode_index),
            "shape_id": int(self.shape.shape_id),
            "shape": self.shape.name,
        }

    @property
    def target_object(self):
        return self.obj

    def failure_category(self, info: dict, grasp: GraspHistory) -> str | None:
        """From the last stage backwards: over the slot but not down in it, brought to the slot but off in
        position or yaw, never grasped, carried but not brought, let go away from the slot (`released`) or slipped
        out of the closed hand (`dropped`)."""
        if info["success"]:
            return None
        if info["pos_correct"] and info["rot_correct"]:
            return "not_inserted"
        if float(info["pos_diff_norm"]) < NEAR_SLOT:
            return "misaligned"
        if not grasp.ever_grasped:
            return "never_grasped"
        if grasp.held_at_end:
            return "not_transported"
        return "released" if grasp.released else "dropped"

    def tracked_frames(self):
        frames = super().tracked_frames()
        frames[self.board.name] = (self.board.pose.p, self.board.pose.q)
        frames["goal"] = (self.goal_pos, yaw_quat(self.goal_rot))
        return frames

    # -- building ------------------------------------------------------------------------------
    def _render_camera(self):
        return CameraSpec.looking_at("render_camera", [0.3, 0.3, 0.8], [0.0, 0.0, 0.1], 512, 512, 1.0)

    def _load_task(self, scene, render):
        # The kit is chosen in _initialize_episode (it needs the episode rng), which builds it then.
        self.board: sapien.Entity
        self.obj: sapien.Entity
        self.static_shapes = []

    def _build_kit(self, episode_index: int) -> None:
        episode = self.episodes[episode_index]
        render = self._renders
        board = self._board(episode_index)
        board_material = physx.PhysxMaterial(BOARD_FRICTION, BOARD_FRICTION, 0.0)
        visual = (board.visual_vertices, board.visual_faces) if render else None
        # One triangle mesh of the board's surface, not its convex pieces: kits/board.py and docs/kit-physics.md.
        self.board = build_static_mesh_actor(
            self.scene,
            "kit",
            board.collision_mesh,
            visual,
            episode.board_color,
            board_material,
            contact_offset=KIT_CONTACT_OFFSET,
        )
        floor = self.episodes.board.floor
        self.static_shapes = []
        for i in episode.obj_in_place:
            slot = episode.slots[i]
            geom = shape_geometry(slot.shape_id, self.episodes.board.scale)
            pose = sapien.Pose([slot.pos[0], slot.pos[1], floor], yaw_quat(slot.yaw))
            visual = (geom.visual_vertices, geom.visual_faces) if render else None
            self.static_shapes.append(
                build_convex_actor(
                    self.scene,
                    f"in_place_{i}",
                    geom.convex_pieces,
                    visual,
                    episode.slot_colors[i],
                    "static",
                    board_material,
                    pose=pose,
                    contact_offset=KIT_CONTACT_OFFSET,
                )
            )
        target = episode.target_slot
        geom = shape_geometry(target.shape_id, self.episodes.board.scale)
        visual = (geom.visual_vertices, geom.visual_faces) if render else None
        material = physx.PhysxMaterial(SHAPE_FRICTION, SHAPE_FRICTION, 0.0)
        self.obj = build_convex_actor(
            self.scene,
            "obj_to_place",
            geom.convex_pieces,
            visual,
            episode.slot_colors[episode.obj_to_place],
            "dynamic",
            material,
            density=SHAPE_DENSITY,
            contact_offset=KIT_CONTACT_OFFSET,
        )
        self.obj_body = self.obj.find_component_by_type(physx.PhysxRigidDynamicComponent)
        self.shape = geom
        self.goal_pos, self.goal_rot = self.episodes.goal_pose(episode_index)
        self.floor = floor

    def segmentation_names(self) -> tuple[str, ...]:
        """The kit, the loose shape, and one seated shape per slot of the episode file's largest kit (a seated shape
        is labelled by its slot: `in_place_<slot>`)."""
        slots = max(len(e.slots) for e in self.episodes)
        return ("kit", "obj_to_place", *(f"in_place_{i}" for i in range(slots)))

    def _board(self, index: int):
        """Board geometry takes 10-30 ms to build: keep the most recent ones (bounded, so memory stays flat)."""
        if index in self._boards:
            self._boards.move_to_end(index)
        else:
            self._boards[index] = self.episodes.board_geometry(index)
            if len(self._boards) > BOARD_CACHE_SIZE:
                self._boards.popitem(last=False)
        return self._boards[index]

    def _initialize_episode(self, rng, options):
        n = len(self.episodes)
        index = options.get("episode_index")
        if index is None:
            index = int(rng.integers(n))
        elif not isinstance(index, (int, np.integer)) or not 0 <= index < n:
            raise KitbenchError(f"episode_index {index!r} out of range; valid choices: 0..{n - 1}")
        self.episode_index = int(index)
        self.episode = self.episodes[self.episode_index]
        self._build_kit(self.episode_index)
        x, y, yaw, z = self._spawn_pose(rng)
        self.obj.set_pose(sapien.Pose([x, y, z], yaw_quat(yaw)))

    def _spawn_pose(self, rng) -> tuple[float, float, float, float]:
        """A flat pose for the loose shape: on the board top clear of every pocket, or on the table clear of
        the board, inside the variant's spawn region (rejection sampling, deterministic given the rng)."""
        spec = self.episodes.board
        board_rect = shapely_box(-spec.size[0] / 2, -spec.size[1] / 2, spec.size[0] / 2, spec.size[1] / 2)
        board = self._board(self.episode_index)
        pockets = [p.buffer(SPAWN_MARGIN) for p in board.slot_polygons]
        inner = board_rect.buffer(-SPAWN_MARGIN)
        outer = board_rect.buffer(SPAWN_MARGIN)
        outline = self.shape.outline
        variant = self.kit_variant
        for _ in range(500):
            x, y = rng.uniform(*variant.spawn_x), rng.uniform(*variant.spawn_y)
            yaw = rng.uniform(-math.pi, math.pi)
            placed = place(outline, x, y, yaw)
            if any(placed.intersects(p) for p in pockets):
                continue
            if inner.contains(placed):
                return x, y, yaw, spec.top + 1e-3
            if not outer.intersects(placed):
                return x, y, yaw, 1e-3
        raise RuntimeError(f"no free spawn pose for episode {self.episode_index} after 500 tries")

    # -- evaluation ----------------------------------------------------------------------------
    def evaluate(self):
        pose = self.obj.pose
        p = pose.p
        pos_diff = (self.goal_pos[:2] - p[:2]).astype(np.float32)
        pos_diff_norm = float(np.linalg.norm(pos_diff))
        yaw = planar_yaw(quat_to_matrix(pose.q))
        rot_diff = yaw_error(yaw, self.goal_rot, self.shape.symmetry)
        pos_correct = pos_diff_norm < POS_TOLERANCE
        rot_correct = rot_diff < ROT_TOLERANCE
        in_slot = abs(float(p[2]) - self.floor) < IN_SLOT_TOLERANCE
        return {
            "pos_diff": pos_diff,
            "pos_diff_norm": pos_diff_norm,
            "rot_diff": rot_diff,
            "pos_correct": pos_correct,
            "rot_correct": rot_correct,
            "in_slot": in_slot,
            "success": pos_correct and rot_correct and in_slot,
        }

    def task_state(self):
        obj = self.obj.pose
        tcp_pose = self.robot.tcp_pose()
        tcp = tcp_pose.p
        goal = self.goal_pos.astype(np.float32)
        symmetry = self.shape.symmetry
        obj_yaw = planar_yaw(quat_to_matrix(obj.q))
        tcp_yaw = planar_yaw(quat_to_matrix(tcp_pose.q))
        onehot = np.zeros(NUM_SHAPES, dtype=np.float32)
        onehot[self.shape.shape_id] = 1.0
        tcp_to_obj = (obj.p - tcp).astype(np.float32)
        to_goal = (goal - obj.p).astype(np.float32)
        turn = signed_yaw_error(obj_yaw, self.goal_rot, symmetry)
        return {
            "obj_pose": pose7(obj),
            "obj_yaw_sym": folded_yaw(obj_yaw, symmetry),
            "tcp_to_obj_pos": tcp_to_obj,
            "goal_pos": goal,
            "goal_xy": goal[:2],
            "goal_rot": np.array([self.goal_rot], dtype=np.float32),
            "goal_yaw": np.array([math.cos(self.goal_rot), math.sin(self.goal_rot)], dtype=np.float32),
            "goal_yaw_sym": folded_yaw(self.goal_rot, symmetry),
            "obj_to_goal_pos": to_goal,
            "shape_id": np.array([self.shape.shape_id], dtype=np.int32),
            "shape_onehot": onehot,
            "symmetry": np.array([symmetry], dtype=np.float32),
            "tcp_yaw": np.array([math.cos(tcp_yaw), math.sin(tcp_yaw)], dtype=np.float32),
            "tcp_to_obj_yaw": folded_yaw(obj_yaw - tcp_yaw, math.pi),
            "obj_to_goal_yaw": folded_yaw(self.goal_rot - obj_yaw, symmetry),
            "tcp_to_obj_fine": np.tanh(tcp_to_obj[:2] / FINE_GRASP_SCALE),
            "obj_to_goal_fine": np.tanh(
                np.array([*(to_goal[:2] / FINE_INSERT_SCALE), turn / FINE_TURN_SCALE], dtype=np.float32)
            ),
        }

    def compute_dense_reward(self, info):
        """Staged: reach (1), grasp (1), lift clear of the board (1), align xy (1) and yaw (1) over the slot,
        insert (1); 7 on success. Each stage is earned only once the ones before it hold."""
        if info["success"]:
            return MAX_DENSE_REWARD
        p = self.obj.pose.p
        tcp = self.robot.tcp_pose().p
        reward = 1.0 - math.tanh(5.0 * float(np.linalg.norm(p - tcp)))
        grasped = self.robot.is_grasping(self.obj)
        near_goal = info["pos_diff_norm"] < POS_TOLERANCE
        if not (grasped or near_goal):
            return reward
        reward += 1.0
        spec = self.episodes.board
        clearance = float(p[2]) - spec.top
        align_xy = 1.0 - math.tanh(10.0 * info["pos_diff_norm"])
        half_sym = self.shape.symmetry / 2 if self.shape.symmetry > 0 else math.pi
        align_yaw = 1.0 - min(1.0, info["rot_diff"] / half_sym)
        if near_goal and info["rot_correct"]:
            depth = max(0.0, float(p[2]) - self.floor)
            return reward + 1.0 + align_xy + align_yaw + (1.0 - math.tanh(50.0 * depth))
        return reward + min(1.0, max(0.0, clearance / 0.02)) + align_xy + align_yaw


assert POS_TOLERANCE < NEAR_SLOT
