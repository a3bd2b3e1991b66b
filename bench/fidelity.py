"""Fidelity to ManiSkill 3.0.1: the same actions from the same start, in both simulators, on LiftPegUpright-v1.

    python bench/fidelity.py [--seeds 0-29] [--expert-seeds 0-19] [--out outputs/fidelity] [--fixture-dir DIR]

1. Builds ManiSkill 3.0.1 in a virtualenv of its own with the project's uv (`~/.cache/kitbench/maniskill-3.0.1`;
   mplib needs numpy < 2, which kitbench's environment does not have), once.
2. Runs ManiSkill's own motion-planning solution for LiftPegUpright-v1 (`pd_joint_pos`, mplib) on `--seeds` in
   ManiSkill, and replays each episode's actions open loop in kitbench from ManiSkill's initial arm joints and peg
   pose (`reset(options=...)`).
3. The reverse: kitbench's expert on `--expert-seeds` (`pd_joint_pos`, run on for `--settle` steps after success,
   as the recipes record), replayed open loop in ManiSkill from kitbench's initial state.
4. Prints, per direction: successes in each simulator, the peg's final tilt and height in both, the tilt along the
   trajectory at fixed steps (seed by seed with `--verbose`), and the targets of docs/fidelity.md.
5. Each control mode's answer to the same actions from the same start (`MODE_ACTIONS` in fidelity_maniskill.py):
   the end-effector modes' first TCP target (what the action means) and the TCP along 16 steps in both.

Both directions judge success by the geometric test (the peg's long axis within 0.08 rad of vertical, its centre
within 5 mm of 0.12 m); ManiSkill's own Euler test is printed beside it for ManiSkill's runs. `--fixture-dir DIR`
writes the first `--fixture-episodes` successful ManiSkill episodes (start, actions, the peg along the way) and the
control modes' answers (`FIXTURE_EPISODES`, `FIXTURE_MODES`) for tests/test_fidelity.py, which replays them in CI
without ManiSkill.

AssemblingKits-v1 is not compared here: its assets come from a download that is not available offline;
docs/fidelity.md compares what can be (controllers, the Panda and its hand camera, pocket clearances, thresholds).
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

import kitbench  # noqa: F401  (registers the tasks)
from kitbench.geometry import quat_to_matrix, tilt_from_vertical
from kitbench.policies.joint_targets import joint_target_to_action
from kitbench.tasks.lift_peg_upright import PEG_HALF_LENGTH, peg_success

ROOT = Path(__file__).resolve().parent.parent
MANISKILL = "mani-skill==3.0.1"
# ManiSkill's pins for its side (docs/fidelity.md): its SAPIEN, a torch it runs on, and numpy < 2 for mplib.
MANISKILL_PACKAGES = (MANISKILL, "sapien==3.0.3", "torch==2.11.0", "numpy<2")
VENV = Path(os.environ.get("KITBENCH_MANISKILL_VENV", Path.home() / ".cache/kitbench/maniskill-3.0.1"))
TRACE_STEPS = (25, 50, 75, 100, 125, 150)  # where the tilt along the trajectory is printed
TILT_AGREEMENT = np.deg2rad(2.0)  # the target: final tilts within 2 degrees of ManiSkill's
FIXTURE_EPISODES = "maniskill_lift_peg_upright.npz"
FIXTURE_MODES = "maniskill_control_modes.npz"


def maniskill_python() -> Path:
    """The ManiSkill virtualenv's python, built on first use (a few minutes; from the package index)."""
    python = VENV / "bin/python"
    marker = VENV / ".kitbench-ready"
    if marker.exists():
        return python
    uv = subprocess.run(["bash", "scripts/ensure-uv.sh"], cwd=ROOT, check=True, capture_output=True, text=True)
    uv_path = uv.stdout.strip()
    uv_path = uv_path if os.path.isabs(uv_path) else str(ROOT / uv_path)
    print(f"fidelity: building ManiSkill's virtualenv in {VENV} ({', '.join(MANISKILL_PACKAGES)})", flush=True)
    subprocess.run([uv_path, "venv", "--quiet", "--python", "3.12", str(VENV)], check=True)
    subprocess.run([uv_path, "pip", "install", "--quiet", "--python", str(python), *MANISKILL_PACKAGES], check=True)
    marker.touch()
    return python


def run_maniskill(*args: str) -> None:
    script = ROOT / "bench/fidelity_maniskill.py"
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    subprocess.run([str(maniskill_python()), str(script), *args], check=True, env=env, stdout=subprocess.DEVNULL)


def load_episodes(path: Path) -> list[dict]:
    data = np.load(path)
    keys = ("qpos0", "peg0", "actions", "peg", "tcp", "fingers")
    return [
        {"seed": int(seed), "success": bool(ok), **{k: data[f"{i}/{k}"] for k in keys if f"{i}/{k}" in data}}
        for i, (seed, ok) in enumerate(zip(data["seeds"].tolist(), data["success"].tolist(), strict=True))
    ]


def save_episodes(path: Path, episodes: list[dict], keys=("qpos0", "peg0", "actions", "peg")) -> None:
    data = {"seeds": np.array([e["seed"] for e in episodes]), "success": np.array([e["success"] for e in episodes])}
    for i, e in enumerate(episodes):
        for key in keys:
            data[f"{i}/{key}"] = np.asarray(e[key], dtype=np.float32 if key == "actions" else np.float64)
    np.savez_compressed(path, **data)


def make_env():
    """kitbench's LiftPegUpright in ManiSkill's solution's mode, unwrapped: replays run past the task's 50 steps."""
    return gym.make("kitbench/LiftPegUpright-v1", obs_mode="state", control_mode="pd_joint_pos").unwrapped


def replay_in_kitbench(env, seed: int, qpos0: np.ndarray, peg0: np.ndarray, actions: np.ndarray) -> dict:
    """ManiSkill's `pd_joint_pos` actions (its gripper convention, which kitbench's is) replayed open loop from
    ManiSkill's start: the peg's pose after every step and the geometric verdict at the end."""
    env.reset(seed=seed, options={"arm_qpos": np.asarray(qpos0[:7]), "peg_pose": np.asarray(peg0)})
    poses = []
    for action in actions:
        env.step(np.asarray(action, dtype=np.float32))
        poses.append(np.concatenate([env.peg.pose.p, env.peg.pose.q]))
    final = poses[-1]
    success, _, _ = peg_success(final[:3], final[3:], PEG_HALF_LENGTH)
    return {"success": success, "peg": np.asarray(poses)}


def kitbench_expert_episode(env, seed: int, settle: int, max_steps: int = 200) -> dict:
    """kitbench's expert from the seed's start in `pd_joint_pos`, run `settle` steps past success: its start, its
    actions and the peg's poses."""
    obs, info = env.reset(seed=seed)
    qpos0 = env.robot.qpos().astype(np.float64)
    peg0 = np.concatenate([env.peg.pose.p, env.peg.pose.q]).astype(np.float64)
    expert = env.make_expert()
    expert.reset(obs, info, seed=seed)
    actions, poses, after = [], [], None
    for _ in range(max_steps):
        target = expert.act(obs)
        action = joint_target_to_action(env, target[:-1], float(target[-1]))
        obs, _, _, _, info = env.step(action)
        actions.append(action)
        poses.append(np.concatenate([env.peg.pose.p, env.peg.pose.q]))
        after = after if after is not None or not info["success"] else 0
        if after is not None:
            after += 1
            if after > settle:
                break
    final = poses[-1]
    success, _, _ = peg_success(final[:3], final[3:], PEG_HALF_LENGTH)
    return {
        "seed": seed,
        "success": success,
        "qpos0": qpos0,
        "peg0": peg0,
        "actions": np.asarray(actions),
        "peg": np.asarray(poses),
    }


def tilt_deg(pose) -> float:
    return float(np.rad2deg(tilt_from_vertical(quat_to_matrix(pose[3:])[:, 0])))


def trace(peg: np.ndarray) -> list[str]:
    return [f"{tilt_deg(peg[min(s, len(peg)) - 1]):5.1f}" for s in TRACE_STEPS]


def compare(name: str, source: str, target: str, pairs: list[tuple[dict, dict]], verbose: bool) -> dict:
    """Prints one direction's figures; returns them."""
    both = [(a, b) for a, b in pairs if a["success"]]
    ok = sum(b["success"] for _, b in both)
    final = np.array([abs(tilt_deg(a["peg"][-1]) - tilt_deg(b["peg"][-1])) for a, b in both])
    close = int((np.deg2rad(final) <= TILT_AGREEMENT).sum())
    dz = np.array([abs(a["peg"][-1][2] - b["peg"][-1][2]) * 1000 for a, b in both])
    print(f"\n## {name}")
    print(f"episodes that succeed in {source}: {len(both)} of {len(pairs)}")
    print(f"of those, succeed replayed in {target}: {ok} of {len(both)} ({100 * ok / max(len(both), 1):.1f}%)")
    if len(both):
        print(
            f"final tilt within 2 degrees of {source}'s: {close} of {len(both)}; |difference| median "
            f"{np.median(final):.2f}, max {final.max():.2f} degrees; final height |difference| median "
            f"{np.median(dz):.1f} mm"
        )
        a_tilts = np.array([tilt_deg(a["peg"][-1]) for a, _ in both])
        b_tilts = np.array([tilt_deg(b["peg"][-1]) for _, b in both])
        print(
            f"final tilt in {source}: median {np.median(a_tilts):.2f} (max {a_tilts.max():.2f}); in {target}: "
            f"median {np.median(b_tilts):.2f} (max {b_tilts.max():.2f}) degrees"
        )
    if verbose:
        print(f"tilt (degrees) at steps {', '.join(map(str, TRACE_STEPS))}: {source} | {target}")
        for a, b in pairs:
            print(
                f"  seed {a['seed']:3d} {a['success']!s:5} {b['success']!s:5}  {' '.join(trace(a['peg']))} | "
                f"{' '.join(trace(b['peg']))}"
            )
    return {"source_successes": len(both), "replayed_successes": ok, "tilt_within_2deg": close}


def rotation_deg(a: np.ndarray, b: np.ndarray) -> float:
    """The angle between two rotation matrices, in degrees."""
    return float(np.rad2deg(np.arccos(np.clip((np.trace(a @ b.T) - 1.0) / 2.0, -1.0, 1.0))))


def replay_mode(data, mode: str) -> list[dict]:
    """A control mode's recorded ManiSkill actions (`fidelity_maniskill.py modes`) replayed in kitbench from
    ManiSkill's start: per step the TCP's world pose and the controller's TCP target (base frame), each against
    ManiSkill's (mm, degrees; the target's gap is NaN in joint modes)."""
    env = gym.make("kitbench/LiftPegUpright-v1", obs_mode="state", control_mode=mode).unwrapped
    env.reset(seed=0, options={"arm_qpos": data[f"{mode}/qpos0"][:7], "peg_pose": data[f"{mode}/peg0"]})
    rows = []
    for action, tcp, target in zip(data[f"{mode}/actions"], data[f"{mode}/tcp"], data[f"{mode}/target"], strict=True):
        env.step(np.asarray(action, dtype=np.float32))
        ours = env.robot.tcp_pose()
        row = {
            "tcp_mm": float(np.linalg.norm(ours.p - tcp[:3]) * 1000),
            "tcp_deg": rotation_deg(quat_to_matrix(ours.q), quat_to_matrix(tcp[3:])),
            "target_mm": float("nan"),
            "target_deg": float("nan"),
        }
        mine = env.controller.tcp_target
        if mine is not None and np.isfinite(target).all():
            row["target_mm"] = float(np.linalg.norm(mine[:3, 3] - target[:3]) * 1000)
            row["target_deg"] = rotation_deg(mine[:3, :3], quat_to_matrix(target[3:]))
        rows.append(row)
    env.close()
    return rows


def modes_table(data) -> None:
    modes = sorted({key.split("/")[0] for key in data.files})
    print("\n## Each control mode's answer to ManiSkill's actions (seed 0's start, 16 steps)")
    print("| mode | first TCP target: gap | TCP along the way: largest gap | ManiSkill's TCP moved |")
    print("|---|---|---|---|")
    for mode in modes:
        rows = replay_mode(data, mode)
        first = rows[0]
        target = "-" if np.isnan(first["target_mm"]) else f"{first['target_mm']:.2f} mm, {first['target_deg']:.2f} deg"
        moved = np.linalg.norm(data[f"{mode}/tcp"][-1][:3] - data[f"{mode}/tcp"][0][:3]) * 1000
        print(
            f"| {mode} | {target} | {max(r['tcp_mm'] for r in rows):.1f} mm, {max(r['tcp_deg'] for r in rows):.2f} "
            f"deg | {moved:.0f} mm |"
        )


def parse_seeds(text: str) -> list[int]:
    first, _, last = text.partition("-")
    return list(range(int(first), int(last or first) + 1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0-29", help="ManiSkill solution seeds, FIRST-LAST")
    parser.add_argument("--expert-seeds", default="0-19", help="kitbench expert seeds, FIRST-LAST")
    parser.add_argument("--settle", type=int, default=10, help="steps the expert runs on after success")
    parser.add_argument("--out", type=Path, default=None, help="keep the episodes here (.npz)")
    parser.add_argument("--fixture-dir", type=Path, default=None, help="write the test fixtures here")
    parser.add_argument("--fixture-episodes", type=int, default=4)
    parser.add_argument("--verbose", action="store_true")
    args = parser.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="kitbench-fidelity-"))
    out.mkdir(parents=True, exist_ok=True)
    env = make_env()
    start = time.perf_counter()

    ms_file = out / "maniskill_solution.npz"
    run_maniskill("solve", "--seeds", args.seeds, "--out", str(ms_file))
    ms_episodes = load_episodes(ms_file)
    pairs = [(e, replay_in_kitbench(env, e["seed"], e["qpos0"], e["peg0"], e["actions"])) for e in ms_episodes]
    forward = compare("ManiSkill's solution replayed in kitbench", "ManiSkill", "kitbench", pairs, args.verbose)

    kb_episodes = [kitbench_expert_episode(env, s, args.settle) for s in parse_seeds(args.expert_seeds)]
    kb_file, back_file = out / "kitbench_expert.npz", out / "kitbench_in_maniskill.npz"
    save_episodes(kb_file, kb_episodes)
    run_maniskill("replay", "--episodes", str(kb_file), "--out", str(back_file))
    back = load_episodes(back_file)
    for b in back:  # the geometric test on ManiSkill's final pose (its own Euler test printed apart)
        b["maniskill_success"] = b["success"]
        b["success"] = peg_success(b["peg"][-1][:3], b["peg"][-1][3:], PEG_HALF_LENGTH)[0]
    reverse = compare(
        "kitbench's expert replayed in ManiSkill",
        "kitbench",
        "ManiSkill",
        list(zip(kb_episodes, back, strict=True)),
        args.verbose,
    )
    print(f"(ManiSkill's own Euler test on those replays: {sum(b['maniskill_success'] for b in back)} of {len(back)})")

    print("\n## Targets")
    n, k = forward["source_successes"], forward["replayed_successes"]
    print(f"- ManiSkill's solution in kitbench >= 90%: {k}/{n} {'met' if k >= 0.9 * n else 'NOT met'}")
    c = forward["tilt_within_2deg"]
    print(f"- final tilt within 2 degrees on >= 90% of seeds: {c}/{n} {'met' if c >= 0.9 * n else 'NOT met'}")
    n, k = reverse["source_successes"], reverse["replayed_successes"]
    print(f"- kitbench's expert in ManiSkill >= 90%: {k}/{n} {'met' if k >= 0.9 * n else 'NOT met'}")

    modes_file = out / "maniskill_modes.npz"
    run_maniskill("modes", "--out", str(modes_file))
    modes_table(np.load(modes_file))
    print(f"({time.perf_counter() - start:.0f} s; episodes in {out})")

    if args.fixture_dir:
        chosen = [e for e, r in pairs if e["success"]][: args.fixture_episodes]
        args.fixture_dir.mkdir(parents=True, exist_ok=True)
        save_episodes(args.fixture_dir / FIXTURE_EPISODES, chosen)
        shutil.copyfile(modes_file, args.fixture_dir / FIXTURE_MODES)
        print(f"fixtures: {len(chosen)} episodes and the control modes' answers in {args.fixture_dir}")


if __name__ == "__main__":
    sys.exit(main())
