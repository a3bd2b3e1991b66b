"""Kit insertion physics over every default kit: `python bench/kit_drops.py [--offset-drops K] [--sim-freq HZ]`.

Releases each default episode's target 1 cm above its seated pose and counts, per shape, how often it ends in
its pocket:
- square: turned +-1 degree, centred (must always go in);
- offset: K random poses per kit within +-3 degrees and +-1.5 mm that still fit the pocket with 0.5 mm to spare;
- free 10: asymmetric shapes turned +-10 degrees, free to rotate (a shape landing on the rim can turn itself in);
- held 10: the same with the shape's rotation locked, as a gripper holds it (must never go in).
These are the figures behind docs/kit-physics.md.
"""

from __future__ import annotations

import argparse
import math
import time

import gymnasium as gym
import numpy as np
import sapien

import kitbench  # noqa: F401  (registers the tasks)
from kitbench.geometry import yaw_quat
from kitbench.kits import NUM_SHAPES, SHAPE_NAMES, SYMMETRY, place, shape_geometry, slot_outline
from kitbench.sim.scene import SimConfig

HOLD = np.array([0, 0, 0, 0, 0, 0, 0, -1], dtype=np.float32)


def ends_in_pocket(env, kit: int, dyaw_deg: float, shift=(0.0, 0.0), hold_yaw: bool = False) -> bool:
    """Release the target 1 cm above its seated pose, turned by dyaw and shifted in its own frame."""
    env.reset(seed=0, options={"episode_index": kit})
    if hold_yaw:
        env.obj_body.set_locked_motion_axes([False, False, False, True, True, True])
    c, s = math.cos(env.goal_rot), math.sin(env.goal_rot)
    x = env.goal_pos[0] + c * shift[0] - s * shift[1]
    y = env.goal_pos[1] + s * shift[0] + c * shift[1]
    env.obj.set_pose(
        sapien.Pose([x, y, env.episodes.board.top + 0.01], yaw_quat(env.goal_rot + math.radians(dyaw_deg)))
    )
    for _ in range(20):
        _, _, _, _, info = env.step(HOLD)
    return bool(info["in_slot"])


def fitting_offsets(shape_id: int, count: int, rng: np.random.Generator) -> list[tuple[float, tuple[float, float]]]:
    """Random (yaw offset in degrees, shift) pairs at which the shape fits its pocket with 0.5 mm to spare."""
    outline, room = shape_geometry(shape_id).outline, slot_outline(shape_id).buffer(-0.0005)
    found = []
    while len(found) < count:
        dyaw, shift = rng.uniform(-3, 3), tuple(rng.uniform(-0.0015, 0.0015, 2))
        if room.contains(place(outline, shift[0], shift[1], math.radians(dyaw))):
            found.append((dyaw, shift))
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--offset-drops", type=int, default=4, help="random fitting poses per kit")
    parser.add_argument("--sim-freq", type=int, default=SimConfig().sim_freq, help="physics rate (Hz)")
    args = parser.parse_args()
    env = gym.make("kitbench/AssemblingKits-v1", sim_config=SimConfig(sim_freq=args.sim_freq)).unwrapped
    rng = np.random.default_rng(0)
    columns = ("square", "offset", "free 10", "held 10")
    counts = {c: np.zeros((NUM_SHAPES, 2), dtype=int) for c in columns}  # [shape] -> (in pocket, drops)
    start = time.perf_counter()
    for kit, episode in enumerate(env.episodes):
        sid = episode.target_shape_id
        trials = {
            "square": [(d, (0.0, 0.0), False) for d in (1.0, -1.0)],
            "offset": [(d, s, False) for d, s in fitting_offsets(sid, args.offset_drops, rng)],
        }
        if SYMMETRY[sid] == 2 * math.pi:
            trials["free 10"] = [(d, (0.0, 0.0), False) for d in (10.0, -10.0)]
            trials["held 10"] = [(d, (0.0, 0.0), True) for d in (10.0, -10.0)]
        for column, poses in trials.items():
            for dyaw, shift, held in poses:
                counts[column][sid] += (ends_in_pocket(env, kit, dyaw, shift, held), 1)
    seconds = time.perf_counter() - start
    print(
        f"AssemblingKits-v1: drops into the pocket over {len(env.episodes)} default kits, "
        f"{args.sim_freq} Hz physics (in pocket / drops)"
    )
    print(f"{'shape':<20}" + "".join(f"{c:>12}" for c in columns))
    for sid in range(NUM_SHAPES):
        cells = [f"{counts[c][sid][0]}/{counts[c][sid][1]}" if counts[c][sid][1] else "-" for c in columns]
        print(f"{sid:2d} {SHAPE_NAMES[sid]:<17}" + "".join(f"{cell:>12}" for cell in cells))
    totals = [counts[c].sum(axis=0) for c in columns]
    print(f"{'all':<20}" + "".join(f"{f'{t[0]}/{t[1]}':>12}" for t in totals))
    print(f"{sum(t[1] for t in totals) / seconds:.0f} drops/s ({seconds:.0f} s)")


if __name__ == "__main__":
    main()
