"""What a task's observation cameras see of it along its expert's episodes, phase by phase:

    python bench/camera_view.py --task AssemblingKits-v1 [--camera-size 64] [--camera-view board] [--seeds A:B]
        [--robot R] [--control-mode M] [--expert-option KEY=VALUE] [--out report.json]

Before training a policy from pixels: is what the expert's next move depends on in the picture, and how many
pixels of it? For each expert phase and camera it prints the frames, the pixels of the target object (median; 0
when it is out of view or hidden) and, for every other frame the task tracks (AssemblingKits: its kit and `goal`,
the slot the shape goes into), the share of frames whose origin projects into the image (`in view`) and of those
where that pixel shows neither the robot nor the target object (`seen`: not behind the arm or the held object).
`cut` is the share of frames where the target object touches the image's edge (part of it may be outside the
picture), `hidden` where none of its pixels shows: what a tighter framing (`--camera-view`) must not raise.
The counts come from the segmentation the cameras render at the size asked, the pixels of the rgb images a
policy gets at that size. Seeds 0.. are the recipes' training seeds, the suites start at 1,000,000.
Exit status: 2 for a bad argument.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.open_loop import describe_seeds, parse_seeds, seeds_json  # noqa: E402
from kitbench.errors import KitbenchError  # noqa: E402


def _project(params: dict, point: np.ndarray) -> tuple[int, int] | None:
    """The pixel (column, row) a world point falls on, None when it is behind the camera or outside the image."""
    x, y, z = params["extrinsic_cv"] @ np.append(point, 1.0)
    if z <= 0:
        return None
    u, v, w = params["intrinsic_cv"] @ np.array([x, y, z])
    column, row = int(np.floor(u / w)), int(np.floor(v / w))
    return (column, row) if 0 <= column < params["width"] and 0 <= row < params["height"] else None


def touches_edge(mask: np.ndarray) -> bool:
    """Whether a (H, W) mask has a pixel on the image's border: the object may be cut by the picture's edge."""
    return bool(mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any())


def measure(
    task: str,
    seeds: Sequence[int],
    camera_size: str | None = None,
    robot: str | None = None,
    control_mode: str = "pd_joint_pos",
    expert_options: dict | None = None,
    camera_view: str | None = None,
) -> dict:
    """Per phase (the expert's `phases` order) and camera: the target object's pixel counts and, per tracked frame,
    counts of frames in view and seen."""
    from kitbench.env_settings import PolicyEnvSettings
    from kitbench.policies.expert import ExpertPolicy
    from kitbench.registration import make_env

    cameras = PolicyEnvSettings(task=task, robot=robot, camera_size=camera_size, camera_view=camera_view)
    env = make_env(
        task,
        obs_mode="segmentation",
        control_mode=control_mode,
        robot_uids=robot,
        sensor_configs=cameras.sensor_configs,
    )
    u = env.unwrapped
    names = u.segmentation_id_map
    links = {link.name for link in u.robot.articulation.links}
    target_name = u.target_object.name
    target = np.array([i for i, n in names.items() if n == target_name])
    hiding = np.array([i for i, n in names.items() if n in links or n == target_name])  # what covers a frame
    rows: dict = defaultdict(
        lambda: defaultdict(lambda: {"frames": 0, "object_px": [], "cut": 0, "in_view": {}, "seen": {}})
    )
    order: Sequence[str] = ()
    try:
        for seed in seeds:
            obs, info = env.reset(seed=seed)
            expert = ExpertPolicy(expert_options)
            expert.reset(env, seed, obs, info)
            order = type(expert.planner).phases
            while True:
                obs, _, terminated, truncated, info = env.step(expert.act(obs))
                frames = {k: np.asarray(p, dtype=np.float64) for k, (p, _) in u.tracked_frames().items()}
                frames.pop(target_name, None)
                for camera, data in obs["sensor_data"].items():
                    label = data["segmentation"][..., 0]
                    params = {**obs["sensor_param"][camera], "height": label.shape[0], "width": label.shape[1]}
                    row = rows[expert.phase or "done"][camera]
                    row["frames"] += 1
                    mask = np.isin(label, target)
                    row["object_px"].append(int(mask.sum()))
                    row["cut"] += touches_edge(mask)
                    for name, point in frames.items():
                        pixel = _project(params, point)
                        row["in_view"][name] = row["in_view"].get(name, 0) + (pixel is not None)
                        seen = pixel is not None and not np.isin(label[pixel[1], pixel[0]], hiding)
                        row["seen"][name] = row["seen"].get(name, 0) + bool(seen)
                if terminated or truncated or info["success"]:
                    break
    finally:
        env.close()
    ordered = sorted(rows, key=lambda p: order.index(p) if p in order else len(order))
    return {
        "task": task,
        "seeds": seeds_json(seeds),
        "camera_size": cameras.camera_size,
        "camera_view": camera_view,
        "target_object": target_name,
        "phases": {p: dict(rows[p]) for p in ordered},
    }


def summarize(measured: dict) -> list[dict]:
    """One row per phase and camera: frames, the target object's median pixels, and each tracked frame's share of
    frames in view and seen."""
    out = []
    for phase, cameras in measured["phases"].items():
        for camera, row in cameras.items():
            n = row["frames"]
            out.append(
                {
                    "phase": phase,
                    "camera": camera,
                    "frames": n,
                    "object_px": float(np.median(row["object_px"])),
                    "cut": row["cut"] / n,
                    "hidden": sum(px == 0 for px in row["object_px"]) / n,
                    "in_view": {k: v / n for k, v in row["in_view"].items()},
                    "seen": {k: v / n for k, v in row["seen"].items()},
                }
            )
    return out


def print_table(rows: list[dict], target: str) -> None:
    tracked = sorted({k for r in rows for k in r["in_view"]})
    head = f"{'phase':<10} {'camera':<13} {'frames':>6}  {target + ' px':>{max(9, len(target) + 3)}}    cut  hidden"
    print(head + "".join(f"  {name + ' in view / seen':>22}" for name in tracked))
    for r in rows:
        line = f"{r['phase']:<10} {r['camera']:<13} {r['frames']:>6}  {r['object_px']:>{max(9, len(target) + 3)}.0f}"
        line += f"  {r['cut']:>5.0%}  {r['hidden']:>6.0%}"
        line += "".join(f"  {r['in_view'][k]:>12.0%} / {r['seen'][k]:>5.0%}" for k in tracked)
        print(line)
    print(
        f"({target} px: median pixels of the target object; cut: it touches the image's edge; hidden: none of it "
        "shows; in view: a frame's origin projects into the image; seen: and that pixel shows neither the robot nor "
        "the target object)"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--task", required=True)
    parser.add_argument("--robot", help="the robot (default: the task's own)")
    parser.add_argument("--camera-size", help="WxH or one side (default: the cameras' own, 128x128)")
    parser.add_argument("--camera-view", help="a framing of the cameras the task declares (default: their own)")
    parser.add_argument("--control-mode", default="pd_joint_pos", help="the expert's control mode")
    parser.add_argument("--seeds", default="1000000:1000012", help="N (seeds 0..N-1), A:B or S1,S2,...")
    parser.add_argument("--expert-option", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--out", help="also write the rows to this JSON file")
    args = parser.parse_args(argv)
    try:
        from kitbench.env_settings import EnvSettings
        from kitbench.policies.lerobot_policy import parse_option

        settings = EnvSettings(
            task=args.task,
            robot=args.robot,
            camera_size=args.camera_size,
            camera_view=args.camera_view,
            control_mode=args.control_mode,
        )
        settings.check_robot()
        settings.check_camera_view()
        seeds = parse_seeds(args.seeds)
        options = dict(map(parse_option, args.expert_option))
        measured = measure(args.task, seeds, args.camera_size, args.robot, args.control_mode, options, args.camera_view)
    except KitbenchError as exc:
        print(f"camera_view: error: {exc}", file=sys.stderr)
        return 2
    rows = summarize(measured)
    size = measured["camera_size"] or "the cameras' own size"
    view = f", camera view {args.camera_view}" if args.camera_view else ""
    print(f"{args.task}, seeds {describe_seeds(seeds)}, the expert's episodes, cameras at {size}{view}:")
    print_table(rows, measured["target_object"])
    if args.out:
        Path(args.out).write_text(
            json.dumps({**{k: v for k, v in measured.items() if k != "phases"}, "rows": rows}, indent=1) + "\n"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
