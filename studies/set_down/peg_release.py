"""Where a LiftPegUpright policy holds the peg, and how upright the peg is when the hand lets it go, seed by seed.

    python studies/set_down/peg_release.py --policy lerobot:<checkpoint> --seeds 1000000:1000020 [--out rows.json]
    python studies/set_down/peg_release.py --policy expert --robot so101 --seeds 1000000:1000020 \
        [--policy-option K=V ...]

For each seed the policy plays the episode to its end (the task ends it at the first success). It prints where the
hand closed along the peg (the TCP's distance from the peg's centre along its axis, mm, three steps after the
grasp began), and at the step the grasp ended: the peg's tilt from vertical (the success test wants under
`MAX_TILT`), the peg's centre above its standing height (mm), and whether the hand opened in that step (let go) or
the peg slipped from a closed hand; then how the episode ended. A peg still held when the episode ends reads "held".

The peg's tilt splits into the hand's part and the grip's: `hand` is the tilt the hand's own orientation gives the
peg as it lay in the hand when the grasp was read, `in hand` how far the peg has turned in the hand since. And
`upright`: the step the hand held the peg nearest upright (least `hand` tilt), that tilt, and the peg's height
above standing then; a hand that holds the peg upright in the air and then tilts it again shows there.

The episodes are played one at a time, so an episode `kitbench eval` scored in a batch may come out otherwise; each
row says how the replay ended. Exit status: 2 for a bad argument.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.open_loop import parse_seeds  # noqa: E402
from kitbench.errors import KitbenchError, one_line  # noqa: E402

TASK = "LiftPegUpright-v1"
GRASP_READ = 3  # steps after the grasp began at which the hand's place along the peg is read


def play(env, policy, seed: int) -> dict:
    """One episode of `policy` from `seed`: the grasp's place along the peg, the peg held nearest upright, the peg
    as the grasp ended, the end."""
    from kitbench.envs.grasp import GraspHistory
    from kitbench.evaluation.outcomes import watch_grasp
    from kitbench.geometry import quat_to_matrix, tilt_from_vertical
    from kitbench.tasks.lift_peg_upright import PEG_HALF_LENGTH

    u = env.unwrapped
    obs, info = env.reset(seed=seed)
    policy.reset(env, seed, obs, info)
    history, grasped_at, along, lost = GraspHistory(), None, None, None
    axis_in_hand, upright = None, None  # the peg's axis in the TCP's frame as the grasp was read
    standing = u.peg_scale * PEG_HALF_LENGTH
    for step in range(u.max_episode_steps):
        obs, _, terminated, truncated, info = env.step(policy.act(obs))
        was_held = history.held_at_end
        watch_grasp(env, history)
        peg, tcp = u.peg.pose, u.robot.tcp_pose()
        peg_rotation, hand_rotation = quat_to_matrix(peg.q), quat_to_matrix(tcp.q)
        axis_now = hand_rotation.T @ peg_rotation[:, 0]  # the peg's axis in the TCP's frame this step
        above = (float(peg.p[2]) - standing) * 1000
        if history.held_at_end and grasped_at is None:
            grasped_at = step
        if grasped_at is not None and along is None and step >= grasped_at + GRASP_READ - 1:
            offset = peg_rotation.T @ (np.asarray(tcp.p) - np.asarray(peg.p))
            along = abs(float(offset[0])) * 1000
            axis_in_hand = axis_now
        hand_tilt = None if axis_in_hand is None else math.degrees(tilt_from_vertical(hand_rotation @ axis_in_hand))
        if history.held_at_end and hand_tilt is not None and (upright is None or hand_tilt < upright["hand_deg"]):
            upright = {"step": step, "hand_deg": hand_tilt, "above_mm": above}
        if was_held and not history.held_at_end:
            lost = {
                "step": step,
                "tilt_deg": math.degrees(float(info["tilt"])),
                "above_mm": above,
                "let_go": history.released,
                "hand_deg": hand_tilt,
                "in_hand_deg": None
                if axis_in_hand is None
                else math.degrees(math.acos(min(1.0, abs(float(axis_in_hand @ axis_now))))),
            }
        if terminated or truncated:
            break
    return {
        "seed": seed,
        "grasped_at": grasped_at,
        "along_mm": along,
        "upright": upright,
        "lost": lost if not history.held_at_end else None,
        "success": bool(info["success"]),
        "final_tilt_deg": math.degrees(float(info["tilt"])),
    }


def measure(policy_spec: str, seeds: list[int], robot: str | None, options: dict) -> tuple[list[dict], str]:
    from kitbench.env_settings import PolicyEnvSettings
    from kitbench.policies.registry import make_policy
    from kitbench.registration import make_env

    policy = make_policy(policy_spec, options=options)
    needs = policy.requirements() if hasattr(policy, "requirements") else {}
    robot = needs.get("robot") or robot
    cameras = PolicyEnvSettings(
        task=TASK, robot=robot, camera_size=needs.get("camera_size"), camera_view=needs.get("camera_view")
    )
    env = make_env(
        TASK,
        obs_mode=needs.get("obs_mode", "state"),
        control_mode=needs.get("control_mode", "pd_joint_pos"),
        robot_uids=robot,
        sensor_configs=cameras.sensor_configs,
    )
    try:
        return [play(env, policy, seed) for seed in seeds], env.unwrapped.robot_uid
    finally:
        env.close()


def print_rows(rows: list[dict]) -> None:
    from kitbench.tasks.lift_peg_upright import MAX_TILT

    print(f"{'seed':>8}  along  {'held nearest upright':<26} {'as the grasp ended':<56} end")
    for r in rows:
        along = "  -  " if r["along_mm"] is None else f"{r['along_mm']:5.1f}"
        up, lost = r["upright"], r["lost"]
        near = "" if up is None else f"t={up['step']:3d} {up['hand_deg']:4.1f} deg, {up['above_mm']:5.1f} mm up"
        if r["grasped_at"] is None:
            cell = "never grasped"
        elif lost is None:
            cell = "held"
        else:
            how = "let go" if lost["let_go"] else "slipped"
            parts = (
                ""
                if lost["hand_deg"] is None
                else f" (hand {lost['hand_deg']:4.1f}, in hand {lost['in_hand_deg']:3.1f})"
            )
            cell = (
                f"t={lost['step']:3d} {how:<7} tilt {lost['tilt_deg']:4.1f} deg{parts}, {lost['above_mm']:5.1f} mm up"
            )
        end = "success" if r["success"] else f"failed, tilt {r['final_tilt_deg']:.0f} deg"
        print(f"{r['seed']:>8}  {along}  {near:<26} {cell:<56} {end}")
    limit = math.degrees(MAX_TILT)
    let_go = [r for r in rows if r["lost"] and r["lost"]["let_go"]]
    leaning = [r for r in let_go if r["lost"]["tilt_deg"] > limit]
    print(
        f"{len(let_go)} of {len(rows)} let go of the peg, {len(leaning)} of them while it leaned past the success "
        f"test's {limit:.1f} deg; "
        f"{sum(1 for r in rows if r['lost'] and not r['lost']['let_go'])} slipped; {sum(r['success'] for r in rows)} "
        "succeeded"
    )
    passed = [r for r in leaning if r["upright"] and r["upright"]["hand_deg"] < limit]
    if passed:
        above = np.median([r["upright"]["above_mm"] for r in passed])
        hand = np.median([r["lost"]["hand_deg"] for r in passed])
        print(
            f"{len(passed)} of the {len(leaning)} had held the peg within {limit:.1f} deg of upright, a median "
            f"{above:.1f} mm above its standing height, and let go with the hand tilting it {hand:.1f} deg"
        )
    print(
        "(along: the hand's place along the peg from its centre, mm; up: the peg's centre above its standing height;"
        " hand: the tilt the hand's own orientation gives the peg as it was gripped; in hand: how far it turned in the"
        " grip since)"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--policy", required=True, help="lerobot:<checkpoint> or expert")
    parser.add_argument("--seeds", required=True, help="A:B (B not included), a count N or S1,S2,...")
    parser.add_argument("--robot", help="for a policy without a checkpoint (default the task's first)")
    parser.add_argument("--policy-option", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--out", help="also write the rows to this JSON file")
    args = parser.parse_args(argv)
    try:
        seeds = list(parse_seeds(args.seeds))
        from kitbench.policies.lerobot_policy import parse_option

        rows, robot = measure(args.policy, seeds, args.robot, dict(parse_option(o) for o in args.policy_option))
    except (KitbenchError, OSError, ValueError) as exc:
        print(f"peg_release: error: {one_line(exc, typed=False)}", file=sys.stderr)
        return 2
    print(f"{args.policy} on {TASK} ({robot}):")
    print_rows(rows)
    if args.out:
        Path(args.out).write_text(json.dumps({"policy": args.policy, "robot": robot, "rows": rows}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
