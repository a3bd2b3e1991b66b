"""Open-loop precision of a trained policy: on the states the expert visits, where does the policy's next action
lead, against the expert's own, phase by phase?

    python bench/open_loop.py CHECKPOINT --task AssemblingKits-v1 [--seeds 0:20 | N | S1,S2,...] [--out report.json]

For each seed the task's expert runs the episode (in the control mode the checkpoint was trained in, with the
robot it was trained on). At every step the checkpoint predicts its action chunk from the same observation, and
the first action of that chunk is compared with the expert's (Diffusion, which predicts from its last
`n_obs_steps` observations, is run re-planning every step on the expert's states, so each of its actions is a
fresh prediction, as AssemblingKits' config uses it): both are turned into the joint targets they would
set from the measured state (`Controller.preview`, so every mode compares alike) and those into TCP poses. Per
expert phase it prints the frames, the TCP's horizontal and vertical distance between the two (median and p90,
mm), the angle between their orientations (median, degrees), the difference of their gripper commands (median,
of the -1..1 range), and how far the expert's own TCP target moves per step there, for scale.

Only the policy's error on states from the demonstrations' distribution is measured: no error compounds, so an
error seen here is the fit's own. Seeds 0.. are the recipes' training seeds, the suites start at 1,000,000.
Exit status: 2 for a bad argument.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from kitbench.errors import KitbenchError


def parse_seeds(text: str) -> Sequence[int]:
    """`A:B` (A included, B not), a count `N` (0..N-1) or a list `S1,S2,...` (the seeds of one group of episodes, e.g.
    those a policy failed in the same way)."""
    start, sep, stop = text.partition(":")
    seeds: Sequence[int]
    try:
        if "," in text:
            seeds = [int(s) for s in text.split(",")]
        else:
            seeds = range(int(start), int(stop)) if sep else range(int(text))
    except ValueError:
        seeds = range(0)
    if not seeds or min(seeds) < 0:
        raise KitbenchError(
            f"--seeds {text!r} must be a count N, a range A:B of seeds >= 0 with A < B, or a list S1,S2,... of "
            "seeds >= 0"
        )
    return seeds


def describe_seeds(seeds: Sequence[int]) -> str:
    return f"{seeds.start}..{seeds.stop - 1}" if isinstance(seeds, range) else ",".join(map(str, seeds))


def seeds_json(seeds: Sequence[int]) -> list[int]:
    """A range as [start, stop], a list as itself."""
    return [seeds.start, seeds.stop] if isinstance(seeds, range) else list(seeds)


def _rotation_angle(a: np.ndarray, b: np.ndarray) -> float:
    """Degrees between two 3x3 rotations."""
    cos = (np.trace(a.T @ b) - 1.0) / 2.0
    return math.degrees(math.acos(max(-1.0, min(1.0, cos))))


def measure(checkpoint: str, task: str, seeds: Sequence[int], expert_options: dict | None = None) -> dict:
    """Per phase (in the order the expert's `phases` declares them): lists of the horizontal, vertical (m) and
    angular (deg) distances between where the policy's action and the expert's lead, the differences of their
    gripper commands and the expert's step lengths (m). The expert runs with `expert_options`, by default those
    of the expert that recorded the checkpoint's training data (`close_steps=8`: the states it learned from)."""
    from kitbench.env_settings import PolicyEnvSettings
    from kitbench.policies.expert import ExpertPolicy
    from kitbench.policies.lerobot_policy import LeRobotPolicy, trained_setting
    from kitbench.registration import make_env

    policy = LeRobotPolicy(checkpoint)
    if expert_options is None:
        expert_options = trained_setting(policy.path, "expert_options") or {}
    if policy.config.type == "act":

        def predict(obs):
            return policy.action_chunk(obs)[0]  # the chunk from this observation alone, nothing queued
    else:
        # a policy with an observation window: one action a prediction, so the next prediction sees the next state
        policy = LeRobotPolicy(checkpoint, options={"n_action_steps": 1})
        predict = policy.act
    needs = policy.requirements()
    # the cameras at the size and where they stood when the policy was trained
    cameras = PolicyEnvSettings(
        task=task, robot=needs.get("robot"), camera_size=needs.get("camera_size"), camera_view=needs.get("camera_view")
    )
    env = make_env(
        task,
        obs_mode=needs.get("obs_mode", "state"),
        control_mode=needs.get("control_mode", "pd_joint_pos"),
        robot_uids=needs.get("robot"),
        sensor_configs=cameras.sensor_configs,
    )
    u = env.unwrapped
    n_arm = u.action_space.shape[0] - 1
    phases: dict[str, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    try:
        for seed in seeds:
            obs, info = env.reset(seed=seed)
            expert = ExpertPolicy(expert_options)
            expert.reset(env, seed, obs, info)
            policy.reset(env, seed, obs, info)
            previous = None
            while True:
                label = expert.act(obs)
                predicted = predict(obs)
                qpos = u.robot.arm_qpos()
                kinematics = u.controller.kinematics
                want = kinematics.tcp_pose(u.controller.preview(u.action_to_sim(label)[:n_arm], qpos))
                got = kinematics.tcp_pose(u.controller.preview(u.action_to_sim(predicted)[:n_arm], qpos))
                row = phases[expert.phase or "policy"]
                row["horizontal"].append(float(np.linalg.norm(want[:2, 3] - got[:2, 3])))
                row["vertical"].append(float(abs(want[2, 3] - got[2, 3])))
                row["rotation"].append(_rotation_angle(want[:3, :3], got[:3, :3]))
                row["gripper"].append(float(abs(label[-1] - predicted[-1])))
                if previous is not None:
                    row["expert_step"].append(float(np.linalg.norm(want[:3, 3] - previous[:3, 3])))
                previous = want
                obs, _, terminated, truncated, _ = env.step(label)
                if terminated or truncated:
                    break
        order = type(expert.planner).phases
    finally:
        env.close()
    ordered = {p: phases[p] for p in sorted(phases, key=lambda p: order.index(p) if p in order else len(order))}
    return {
        "checkpoint": checkpoint,
        "task": task,
        "seeds": seeds_json(seeds),
        "expert_options": expert_options,
        "phases": ordered,
    }


def summarize(measured: dict) -> list[dict]:
    """One row per phase."""
    rows = []
    for phase, values in measured["phases"].items():
        horizontal, vertical = np.array(values["horizontal"]) * 1000, np.array(values["vertical"]) * 1000
        step = np.array(values["expert_step"]) * 1000 if values["expert_step"] else np.array([math.nan])
        rows.append(
            {
                "phase": phase,
                "frames": len(horizontal),
                "horizontal_mm": [float(np.median(horizontal)), float(np.percentile(horizontal, 90))],
                "vertical_mm": [float(np.median(vertical)), float(np.percentile(vertical, 90))],
                "rotation_deg": float(np.median(values["rotation"])),
                "gripper_diff": float(np.median(values["gripper"])),
                "expert_step_mm": float(np.median(step)),
            }
        )
    return rows


def print_table(rows: list[dict]) -> None:
    head = f"{'phase':<10} {'frames':>6}  {'horizontal mm':>15}  {'vertical mm':>13}  {'rot deg':>7}  "
    print(head + f"{'gripper':>7}  {'expert step mm':>14}")
    for r in rows:
        h, v = r["horizontal_mm"], r["vertical_mm"]
        print(
            f"{r['phase']:<10} {r['frames']:>6}  {h[0]:6.2f} / {h[1]:6.2f}  {v[0]:5.2f} / {v[1]:5.2f}  "
            f"{r['rotation_deg']:7.2f}  {r['gripper_diff']:7.3f}  {r['expert_step_mm']:14.2f}"
        )
    print("(median / p90; gripper: the median difference of the two commands, -1 closed .. 1 open)")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint", help="a lerobot-train output folder or its pretrained_model")
    parser.add_argument("--task", required=True, help="the task the checkpoint was trained on")
    parser.add_argument("--seeds", default="20", help="N (seeds 0..N-1), A:B or S1,S2,... (default 20)")
    parser.add_argument("--out", help="also write the rows, and the settings, to this JSON file")
    parser.add_argument(
        "--expert-option",
        action="append",
        default=None,
        metavar="KEY=VALUE",
        help="the expert's planner setting (repeatable; default: those of the expert that recorded the training data)",
    )
    args = parser.parse_args(argv)
    try:
        from kitbench.registration import task_entry

        task_entry(args.task)
        seeds = parse_seeds(args.seeds)
        from kitbench.policies.lerobot_policy import parse_option

        options = None if args.expert_option is None else dict(map(parse_option, args.expert_option))
        measured = measure(args.checkpoint, args.task, seeds, options)
    except KitbenchError as exc:
        print(f"open_loop: error: {exc}", file=sys.stderr)
        return 2
    rows = summarize(measured)
    settings = ", ".join(f"{k}={v}" for k, v in measured["expert_options"].items())
    print(
        f"{args.checkpoint} on {args.task}, seeds {describe_seeds(seeds)}, expert's states"
        + (f" ({settings})" if settings else "")
        + ":"
    )
    print_table(rows)
    if args.out:
        report = {
            "checkpoint": args.checkpoint,
            "task": args.task,
            "seeds": seeds_json(seeds),
            "expert_options": measured["expert_options"],
            "rows": rows,
        }
        Path(args.out).write_text(json.dumps(report, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
