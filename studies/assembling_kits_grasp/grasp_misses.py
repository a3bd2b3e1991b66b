"""Where a policy closes the hand in AssemblingKits, against where the expert does, seed by seed.

    python studies/assembling_kits_grasp/grasp_misses.py --policy lerobot:<run>/act/train \
        --report <run>/act/eval/report.json
    python studies/assembling_kits_grasp/grasp_misses.py --policy lerobot:<checkpoint> --seeds 1000000,1000009 \
        [--out misses.json]

For each seed (with `--report`: the seeds of a `kitbench eval` report that ended in `--failure`, never_grasped by
default) the policy plays the episode until it first commands the gripper closed, and so does the expert. At that
step it prints the hand's offset from the shape (table plane and height, mm), the closing direction in the shape's
frame and the opening that direction needs, how far the open fingertips come down from an obstacle (a seated shape,
or the board's edge for a shape on the table: `kitbench.kits.fingers`, the clearance the expert chooses its grasp
by), and how wide the hand still is six steps later (a grasp that closed on the shape reads the shape's width).

The episodes are played again one at a time, so an episode that `kitbench eval` scored in a batch may come out
otherwise; each row says how the replay ended. Exit status: 2 for a bad argument.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

from kitbench.errors import KitbenchError, one_line

TASK = "AssemblingKits-v1"
SETTLE = 6  # steps after the close command at which the hand's opening is read
MAX_STEPS = 200


def seeds_from(report: str, failure: str, limit: int) -> list[int]:
    data = json.loads(Path(report).read_text())
    if data.get("task") != TASK:
        raise KitbenchError(f"--report {report!r} scores {data.get('task')!r}, not {TASK}")
    from kitbench.tasks.assembling_kits import AssemblingKitsEnv

    valid = sorted(AssemblingKitsEnv.failure_categories)
    if failure not in valid:
        raise KitbenchError(f"--failure {failure!r} is not a failure category; valid choices: {', '.join(valid)}")
    return [e["seed"] for e in data["per_episode"] if e.get("failure") == failure][:limit]


def first_close(env, policy, seed: int) -> dict | None:
    """Play `policy` from `seed` until its first close command; the grasp's geometry then, the hand's opening
    `SETTLE` steps later and how the episode ended (played on to its end)."""
    from kitbench.geometry import planar_yaw, quat_to_matrix
    from kitbench.kits import shape_geometry
    from kitbench.kits.fingers import fingertip_clearance, pick_obstacles
    from kitbench.kits.shapes import grasp_width_at

    u = env.unwrapped
    obs, info = env.reset(seed=seed)
    policy.reset(env, seed, obs, info)
    row = None
    for step in range(MAX_STEPS):
        action = policy.act(obs)
        if row is None and action[-1] < 0:  # the hand commanded closed (ManiSkill's sign: -1 closes)
            tcp, obj = u.robot.tcp_pose(), u.obj.pose
            offset = (np.asarray(obj.p) - np.asarray(tcp.p)) * 1000
            obj_yaw = planar_yaw(quat_to_matrix(obj.q))
            # the hand yaw whose fingers close along `closing` is closing + 90 degrees (the planner's rule)
            closing = planar_yaw(quat_to_matrix(tcp.q)) - math.pi / 2
            in_shape = (closing - obj_yaw) % math.pi
            obstacles = pick_obstacles(u.episode, u.episodes.board, float(obj.p[2]))
            row = {
                "step": step,
                "offset_xy_mm": float(np.linalg.norm(offset[:2])),
                "hand_above_mm": float(-offset[2]),
                "closing_deg": math.degrees(in_shape),
                "needs_mm": 1000 * grasp_width_at(shape_geometry(u.shape.shape_id).outline, in_shape),
                "clearance_mm": 1000 * fingertip_clearance(obj.p[:2], closing, obstacles, swept=True),
            }
        if row is not None and step == row["step"] + SETTLE:
            row["opening_after_mm"] = 1000 * u.robot.gripper_opening()
        obs, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            break
    if row is not None:
        row.setdefault("opening_after_mm", 1000 * u.robot.gripper_opening())
        row["success"] = bool(info["success"])
    return row


def measure(policy_spec: str, seeds: list[int], control_mode: str | None) -> list[dict]:
    from kitbench.policies.expert import ExpertPolicy
    from kitbench.policies.registry import make_policy
    from kitbench.registration import make_env

    policy = make_policy(policy_spec)
    needs = policy.requirements() if hasattr(policy, "requirements") else {}
    mode = needs.get("control_mode") or control_mode or "pd_ee_delta_pose"
    env = make_env(TASK, obs_mode=needs.get("obs_mode", "state"), control_mode=mode)
    rows = []
    try:
        for seed in seeds:
            pair = {
                who: first_close(env, player, seed) for who, player in (("policy", policy), ("expert", ExpertPolicy()))
            }
            rows.append({"seed": seed, "shape": env.unwrapped.shape.name, **pair})
    finally:
        env.close()
    return rows


def _cell(r: dict | None) -> str:
    if r is None:
        return f"{'never closed':<52}"
    return (
        f"t={r['step']:3d} {r['offset_xy_mm']:5.1f}/{r['hand_above_mm']:5.1f} {r['closing_deg']:4.0f} "
        f"{r['needs_mm']:5.1f} {min(r['clearance_mm'], 99.9):5.1f} {r['opening_after_mm']:5.1f} "
        f"{'ok' if r['success'] else '--'}"
    )


def print_rows(rows: list[dict]) -> None:
    head = "t    off/above  dir  needs clear  open"
    print(f"{'seed':>8} {'shape':<16} policy: {head}    | expert: {head}")
    for row in rows:
        print(f"{row['seed']:>8} {row['shape']:<16} {_cell(row['policy'])} | {_cell(row['expert'])}")
    for who in ("policy", "expert"):
        closes = [row[who] for row in rows if row[who] is not None]
        blocked = sum(r["clearance_mm"] <= 0.0 for r in closes)
        print(f"{who}: {blocked} of {len(closes)} closes came down on an obstacle")
    print(
        "(off: hand to shape in the table plane, above: hand over the shape's origin, mm; dir: closing direction in "
        "the shape's frame, deg; needs: the opening it takes, clear: fingertips from the nearest obstacle, open: "
        f"the hand's opening {SETTLE} steps later, mm; ok/--: how the replayed episode ended)"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--policy", required=True, help="lerobot:<checkpoint>, expert, random or zero")
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--report", help="a kitbench eval report.json: replay its episodes that ended in --failure")
    where.add_argument("--seeds", help="comma-separated seeds")
    parser.add_argument("--failure", default="never_grasped", help="with --report (default never_grasped)")
    parser.add_argument("--max", type=int, default=20, help="with --report: at most this many episodes (default 20)")
    parser.add_argument("--control-mode", help="for a policy without a checkpoint (default pd_ee_delta_pose)")
    parser.add_argument("--out", help="also write the rows to this JSON file")
    args = parser.parse_args(argv)
    try:
        if args.report:
            seeds = seeds_from(args.report, args.failure, args.max)
        else:
            try:
                seeds = [int(s) for s in args.seeds.split(",")]
            except ValueError:
                raise KitbenchError(f"--seeds {args.seeds!r} must be comma-separated integers") from None
        if not seeds:
            raise KitbenchError(f"no episode to replay: {args.report or args.seeds!r} has none ending {args.failure}")
        rows = measure(args.policy, seeds, args.control_mode)
    except (KitbenchError, OSError, ValueError) as exc:  # ValueError: a report that is not JSON, a policy's mismatch
        print(f"grasp_misses: error: {one_line(exc, typed=False)}", file=sys.stderr)
        return 2
    print(f"{args.policy} on {TASK}, first close command per episode:")
    print_rows(rows)
    if args.out:
        Path(args.out).write_text(json.dumps({"policy": args.policy, "task": TASK, "rows": rows}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
