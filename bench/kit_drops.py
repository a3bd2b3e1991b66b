"""Kit insertion physics over every default kit: `python bench/kit_drops.py [--kits N] [--seeds] [--no-max-yaw]`.

Releases each default kit's loose shape 1 cm above its seated pose (its bottom face level with the board top),
turned by +-1, +-2 and +-10 degrees, and steps the env 30 control steps with the robot holding still. Each drop
ends as one of:
- seated: success (in the pocket, within 4 degrees and 2 cm);
- jammed: still near the goal but not seated (on the rim, tilted, wedged);
- ejected: thrown out of the 2 cm goal disc;
- non-finite: PhysX diverged (the env ends the episode with `info["physics_error"]`);
- misrotated: in the pocket (`in_slot`) but outside the 4-degree tolerance, which the pockets must rule out.
A drop 1 or 2 degrees off must always seat; 10 degrees off a shape may turn itself straight as it tips in.

Per shape, it also measures how far the shape can turn and still enter its pocket: held at a yaw (rotation locked,
as a gripper holds it) and shifted as far into the pocket as that yaw allows (kits/clearance.py), it is released
1 mm above the board top; bisection finds the largest yaw at which it ends `in_slot`, turning each way, next to
the limit computed from the outline (`kitbench.kits.clearance.max_seated_yaw`).

`--seeds` picks the kits as the issue that led to these sweeps did, by env reset seed 0..N-1 (the env draws the
kit from the seed; some kits come twice, others never) instead of every kit once. These are the figures behind
docs/kit-physics.md (90 s on one core).
"""

from __future__ import annotations

import argparse
import math
import time
from collections import Counter

import gymnasium as gym
import numpy as np
import sapien

import kitbench  # noqa: F401  (registers the tasks)
from kitbench.geometry import yaw_quat
from kitbench.kits import NUM_SHAPES, SHAPE_NAMES, SYMMETRY, shape_outline
from kitbench.kits.clearance import MAX_MODELLED_YAW, max_seated_yaw, required_clearance

HOLD = np.array([0, 0, 0, 0, 0, 0, 0, -1], dtype=np.float32)
YAWS = (1.0, 2.0, 10.0)  # degrees, each released turned both ways
OUTCOMES = ("seated", "jammed", "ejected", "non-finite", "misrotated")
DROP_STEPS = 30
HELD_STEPS = 20


def outcome(info: dict) -> str:
    if "physics_error" in info:
        return "non-finite"
    if info["success"]:
        return "seated"
    if info["in_slot"] and info["pos_correct"] and not info["rot_correct"]:
        return "misrotated"
    return "jammed" if info["pos_correct"] else "ejected"


def release(env, dyaw_deg: float, height: float, shift=(0.0, 0.0), hold_yaw: bool = False, steps: int = DROP_STEPS):
    """Put the loose shape `height` above its seated pose, turned by dyaw and shifted (m, in the slot's frame), and
    step the env with the robot holding still; the last info."""
    if hold_yaw:  # free to fall only: whether it enters is up to the pocket's outline alone
        env.obj_body.set_locked_motion_axes([True, True, False, True, True, True])
    c, s = math.cos(env.goal_rot), math.sin(env.goal_rot)
    x = env.goal_pos[0] + c * shift[0] - s * shift[1]
    y = env.goal_pos[1] + s * shift[0] + c * shift[1]
    pose = sapien.Pose([x, y, env.goal_pos[2] + height], yaw_quat(env.goal_rot + math.radians(dyaw_deg)))
    env.obj.set_pose(pose)
    info: dict = {}
    for _ in range(steps):  # on past a success (which ends the episode), so that the shape comes to rest
        _, _, _, _, info = env.step(HOLD)
        if "physics_error" in info:
            break
    return info


def held_enters(env, kit: int, dyaw_deg: float) -> bool:
    """Held at dyaw, shifted as far into the pocket as that yaw allows, released 1 mm above the board top: in_slot?"""
    env.reset(seed=0, options={"episode_index": kit})
    _, shift = required_clearance(shape_outline(env.shape.shape_id), math.radians(dyaw_deg))
    top = env.episodes.board.top - env.goal_pos[2]
    return bool(release(env, dyaw_deg, top + 0.001, shift, hold_yaw=True, steps=HELD_STEPS)["in_slot"])


def simulated_max_yaw(env, kit: int, sense: float, resolution: float = 0.05) -> float:
    """The largest yaw (degrees, turning the way `sense` says) at which the held shape still enters its pocket."""
    lo, hi = 0.0, math.degrees(MAX_MODELLED_YAW)
    while hi - lo > resolution:
        mid = 0.5 * (lo + hi)
        if held_enters(env, kit, math.copysign(mid, sense)):
            lo = mid
        else:
            hi = mid
    return lo


def sweep(env, kits: list[tuple[int, int]]) -> dict[tuple[int, float], Counter]:
    """Drop counts by (shape id, |yaw|) over (reset seed, kit) pairs."""
    counts: dict[tuple[int, float], Counter] = {}
    for seed, kit in kits:
        for dyaw in YAWS:
            for sign in (1.0, -1.0):
                env.reset(seed=seed, options={"episode_index": kit})
                result = outcome(release(env, sign * dyaw, env.episodes.board.pocket_depth))
                counts.setdefault((env.shape.shape_id, dyaw), Counter())[result] += 1
    return counts


def max_yaw_table(env) -> dict[int, tuple[str, str]]:
    """Per shape with a yaw that matters: (analytic, simulated) largest yaw in its pocket, 'ccw / cw' in degrees."""
    kit_of = {}
    for i, episode in enumerate(env.episodes):
        kit_of.setdefault(episode.target_shape_id, i)
    table = {}
    for sid, kit in sorted(kit_of.items()):
        if SYMMETRY[sid] <= 0:
            continue
        clearance = env.episodes.board.clearance[sid]
        limit = min(MAX_MODELLED_YAW, SYMMETRY[sid] / 2)
        analytic = [math.degrees(max_seated_yaw(shape_outline(sid), clearance, limit, s)) for s in (1.0, -1.0)]
        simulated = [simulated_max_yaw(env, kit, s) for s in (1.0, -1.0)]
        table[sid] = (f"{analytic[0]:.2f} / {analytic[1]:.2f}", f"{simulated[0]:.2f} / {simulated[1]:.2f}")
    return table


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kits", type=int, default=None, help="the first N kits (or seeds with --seeds); all")
    parser.add_argument("--seeds", action="store_true", help="pick kits by env reset seed 0..N-1 (N: --kits or 300)")
    parser.add_argument("--no-max-yaw", action="store_true", help="skip the held-yaw bisection per shape")
    args = parser.parse_args()
    env = gym.make("kitbench/AssemblingKits-v1").unwrapped
    n = args.kits if args.kits is not None else len(env.episodes)
    if args.seeds:
        kits = []
        for seed in range(n):
            env.reset(seed=seed)
            kits.append((seed, env.episode_index))
    else:
        kits = [(0, kit) for kit in range(min(n, len(env.episodes)))]
    start = time.perf_counter()
    counts = sweep(env, kits)
    yaws = {} if args.no_max_yaw else max_yaw_table(env)
    seconds = time.perf_counter() - start
    picked = f"reset seeds 0-{n - 1}" if args.seeds else f"{len(kits)} default kits"
    print(
        f"AssemblingKits-v1: loose shape released 1 cm above its seated pose, {DROP_STEPS} steps, robot still "
        f"({picked}); per yaw: {' / '.join(OUTCOMES)}"
    )
    if yaws:
        print("largest yaw in the pocket (degrees, ccw / cw): analytic, and simulated with the yaw held")
    header = f"{'shape':<20}" + "".join(f"{f'+-{y:g} deg':>18}" for y in YAWS)
    print(header + (f"{'analytic':>16}{'simulated':>16}" if yaws else ""))
    totals = {y: Counter() for y in YAWS}
    for sid in range(NUM_SHAPES):
        row = f"{sid:2d} {SHAPE_NAMES[sid]:<17}"
        for y in YAWS:
            c = counts.get((sid, y), Counter())
            totals[y].update(c)
            row += f"{'/'.join(str(c[o]) for o in OUTCOMES):>18}"
        if yaws:
            analytic, simulated = yaws.get(sid, ("any", "any"))
            row += f"{analytic:>16}{simulated:>16}"
        print(row)
    print(f"{'all':<20}" + "".join(f"{'/'.join(str(totals[y][o]) for o in OUTCOMES):>18}" for y in YAWS))
    print(f"{seconds:.0f} s")


if __name__ == "__main__":
    main()
