"""ManiSkill 3.0.1's side of `bench/fidelity.py`: run inside ManiSkill's own virtualenv (mplib needs numpy < 2).

    python fidelity_maniskill.py solve  --seeds 0-29 --out ms.npz        # ManiSkill's LiftPegUpright solution
    python fidelity_maniskill.py replay --episodes kb.npz --out back.npz   # kitbench's episodes, open loop
    python fidelity_maniskill.py modes  --out modes.npz                    # each control mode's answer to actions

Both write one .npz: per episode the initial arm joints and peg pose, the `pd_joint_pos` actions (ManiSkill's
gripper convention: +1 opens), and the peg's pose, the TCP's pose and the finger joints after every step.
Imports nothing of kitbench: it runs where kitbench does not install.
"""

from __future__ import annotations

import argparse

import gymnasium as gym
import numpy as np


def _seeds(text: str) -> list[int]:
    first, _, last = text.partition("-")
    return list(range(int(first), int(last or first) + 1))


class _Recorder(gym.Wrapper):
    """Keeps every action and, after it, the peg's and the TCP's poses and the finger joints."""

    def __init__(self, env):
        super().__init__(env)
        self.actions, self.peg, self.tcp, self.fingers = [], [], [], []

    def step(self, action):
        out = self.env.step(action)
        u = self.env.unwrapped
        self.actions.append(np.asarray(action, dtype=np.float64).reshape(-1))
        self.peg.append(u.peg.pose.raw_pose[0].cpu().numpy().astype(np.float64))
        self.tcp.append(u.agent.tcp.pose.raw_pose[0].cpu().numpy().astype(np.float64))
        self.fingers.append(u.agent.robot.get_qpos()[0, 7:9].cpu().numpy().astype(np.float64))
        return out


def _make():
    import mani_skill.envs  # noqa: F401  (registers the tasks)

    return gym.make(
        "LiftPegUpright-v1",
        obs_mode="none",
        control_mode="pd_joint_pos",
        render_mode=None,
        sim_backend="physx_cpu",
        max_episode_steps=1000,
    )


def _initial(u) -> tuple[np.ndarray, np.ndarray]:
    qpos = u.agent.robot.get_qpos()[0].cpu().numpy().astype(np.float64)
    return qpos, u.peg.pose.raw_pose[0].cpu().numpy().astype(np.float64)


def _pack(episodes: list[dict], out: str) -> None:
    data = {"seeds": np.array([e["seed"] for e in episodes]), "success": np.array([e["success"] for e in episodes])}
    for i, e in enumerate(episodes):
        for key in ("qpos0", "peg0", "actions", "peg", "tcp", "fingers"):
            data[f"{i}/{key}"] = np.asarray(e[key])
    np.savez_compressed(out, **data)


def solve(seeds: list[int], out: str) -> None:
    from mani_skill.examples.motionplanning.panda.solutions.lift_peg_upright import solve as ms_solve

    episodes = []
    for seed in seeds:
        env = _Recorder(_make())
        env.reset(seed=seed)
        qpos0, peg0 = _initial(env.unwrapped)
        result = ms_solve(env, seed=seed)  # resets with the same seed: the same initial state
        if result == -1:
            print(f"seed {seed}: ManiSkill's planner found no plan")
            continue
        success = bool(env.unwrapped.evaluate()["success"][0])
        episodes.append(
            {
                "seed": seed,
                "success": success,
                "qpos0": qpos0,
                "peg0": peg0,
                "actions": env.actions,
                "peg": env.peg,
                "tcp": env.tcp,
                "fingers": env.fingers,
            }
        )
        print(f"seed {seed}: {len(env.actions)} steps, success {success}")
        env.close()
    _pack(episodes, out)


def replay(episodes_file: str, out: str) -> None:
    src = np.load(episodes_file)
    episodes = []
    for i, seed in enumerate(src["seeds"].tolist()):
        env = _Recorder(_make())
        env.reset(seed=int(seed))
        u = env.unwrapped
        u.agent.reset(np.asarray(src[f"{i}/qpos0"], dtype=np.float32))
        peg0 = np.asarray(src[f"{i}/peg0"], dtype=np.float32)
        import sapien

        u.peg.set_pose(sapien.Pose(peg0[:3], peg0[3:]))
        for action in src[f"{i}/actions"]:
            env.step(np.asarray(action, dtype=np.float32))
        success = bool(u.evaluate()["success"][0])
        episodes.append(
            {
                "seed": int(seed),
                "success": success,
                "qpos0": src[f"{i}/qpos0"],
                "peg0": src[f"{i}/peg0"],
                "actions": env.actions,
                "peg": env.peg,
                "tcp": env.tcp,
                "fingers": env.fingers,
            }
        )
        env.close()
    _pack(episodes, out)


# A fixed action for each mode, held for STEPS steps then turned round (the arm part; the gripper stays open).
MODE_ACTIONS = {
    "pd_joint_delta_pos": [0.5, -0.4, 0.3, 0.6, -0.5, 0.4, 0.7],
    "pd_joint_target_delta_pos": [0.5, -0.4, 0.3, 0.6, -0.5, 0.4, 0.7],
    "pd_ee_delta_pos": [0.6, -0.5, 0.4],
    "pd_ee_target_delta_pos": [0.6, -0.5, 0.4],
    "pd_ee_delta_pose": [0.4, -0.3, 0.3, 0.5, -0.4, 0.6],
    "pd_ee_target_delta_pose": [0.4, -0.3, 0.3, 0.5, -0.4, 0.6],
}
STEPS = 8


def modes(out: str) -> None:
    """Each mode from seed 0's start: `MODE_ACTIONS` for STEPS steps, its negative for STEPS more; `pd_joint_pos`
    and `pd_ee_pose` are given absolute targets near the start. The TCP's pose (base frame = world here, the base
    at the origin's offset) after every step."""
    import mani_skill.envs  # noqa: F401

    data = {}
    for mode in [*MODE_ACTIONS, "pd_joint_pos", "pd_ee_pose"]:
        env = gym.make(
            "LiftPegUpright-v1",
            obs_mode="none",
            control_mode=mode,
            render_mode=None,
            sim_backend="physx_cpu",
            max_episode_steps=1000,
        )
        env.reset(seed=0)
        u = env.unwrapped
        qpos0, peg0 = _initial(u)
        if mode == "pd_joint_pos":
            arm = qpos0[:7] + np.array([0.3, -0.2, 0.2, 0.3, -0.3, 0.2, 0.4])
            actions = [np.append(arm, 1.0)] * (2 * STEPS)
        elif mode == "pd_ee_pose":
            base = u.agent.robot.pose.inv() * u.agent.tcp.pose
            p = base.p[0].cpu().numpy() + np.array([0.05, -0.06, -0.08])
            actions = [np.concatenate([p, [np.pi - 0.2, 0.15, 0.3], [1.0]])] * (2 * STEPS)
        else:
            a = np.asarray(MODE_ACTIONS[mode])
            actions = [np.append(a, 1.0)] * STEPS + [np.append(-a, 1.0)] * STEPS
        tcp, target = [], []
        arm = u.agent.controller.controllers["arm"]
        for action in actions:
            env.step(np.asarray(action, dtype=np.float32))
            tcp.append(u.agent.tcp.pose.raw_pose[0].cpu().numpy().astype(np.float64))
            pose = getattr(arm, "_target_pose", None)  # the end-effector modes' TCP target, in the base frame
            target.append(np.full(7, np.nan) if pose is None else pose.raw_pose[0].cpu().numpy().astype(np.float64))
        data[f"{mode}/qpos0"], data[f"{mode}/peg0"] = qpos0, peg0
        data[f"{mode}/actions"], data[f"{mode}/tcp"] = np.asarray(actions), np.asarray(tcp)
        data[f"{mode}/target"] = np.asarray(target)
        env.close()
    np.savez_compressed(out, **data)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    s = sub.add_parser("solve")
    s.add_argument("--seeds", default="0-29")
    s.add_argument("--out", required=True)
    r = sub.add_parser("replay")
    r.add_argument("--episodes", required=True)
    r.add_argument("--out", required=True)
    m = sub.add_parser("modes")
    m.add_argument("--out", required=True)
    args = parser.parse_args()
    if args.command == "solve":
        solve(_seeds(args.seeds), args.out)
    elif args.command == "modes":
        modes(args.out)
    else:
        replay(args.episodes, args.out)


if __name__ == "__main__":
    main()
