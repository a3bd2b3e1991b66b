"""The expert's settings (`--policy-option KEY=VALUE` / a recipe's `policy_options` with `--policy expert`): fields of
its planner's config, checked before anything is written, kept in the recording's settings as part of what a resume
must share, and in the command its card prints."""

from __future__ import annotations

import json
from pathlib import Path

import gymnasium as gym
import pytest

import kitbench  # noqa: F401  (registers the tasks)
from kitbench.errors import KitbenchError
from kitbench.policies.expert import ExpertPolicy
from kitbench.recording.config import load_recipe
from kitbench.recording.convert import convert_config
from kitbench.recording.recorder import RecordConfig, record
from kitbench.tasks.lift_peg_upright import PEG_HALF_LENGTH
from tests import launch
from tests.lerobot_cli import BIN, OFFLINE
from tests.test_recording import _columns

AK = "AssemblingKits-v1"


def _settings(root: Path) -> dict:
    return json.loads((root / "meta/kitbench_recording.json").read_text())


def _grasp_run(options: dict | None, seed: int = 3) -> tuple[list[str], bool]:
    """The expert's phase at each step of one AssemblingKits episode, and whether it succeeded."""
    env = gym.make(f"kitbench/{AK}", obs_mode="state", control_mode="pd_joint_pos")
    try:
        obs, info = env.reset(seed=seed)
        expert = ExpertPolicy(options)
        expert.reset(env, seed, obs, info)
        phases, success = [], False
        for _ in range(env.unwrapped.max_episode_steps):
            obs, _, terminated, truncated, info = env.step(expert.act(obs))
            phases.append(expert.phase)
            success = success or bool(info["success"])
            if terminated or truncated or success:
                break
        return phases, success
    finally:
        env.close()


def test_a_longer_close_holds_the_hand_still_for_that_many_steps_and_still_inserts():
    default, default_success = _grasp_run(None)
    longer, longer_success = _grasp_run({"close_steps": 8})
    assert default_success and longer_success
    assert default.count("grasp") == 2 and longer.count("grasp") == 8
    # everything before the grasp is the same plan
    first = default.index("grasp")
    assert longer[:first] == default[:first] and longer.index("grasp") == first


@pytest.mark.parametrize(
    ("options", "needle"),
    [
        ((("close_step", 8),), "unknown expert option 'close_step' for AssemblingKitsPlanner; valid choices: "),
        ((("close_steps", 2.5),), "expert option close_steps=2.5 for AssemblingKitsPlanner must be an integer"),
        ((("level_held", 1),), "expert option level_held=1 for AssemblingKitsPlanner must be true or false"),
        ((("grasp_height", "low"),), "expert option grasp_height='low' for AssemblingKitsPlanner must be a number"),
    ],
)
def test_a_bad_expert_option_is_one_line_and_writes_nothing(tmp_path, options, needle):
    out = tmp_path / "never"
    with pytest.raises(KitbenchError) as error:
        record(RecordConfig.of(AK, 1, out, policy_options=options, mcap=False), progress=False)
    assert needle in str(error.value) and "\n" not in str(error.value)
    assert not out.exists()


def test_options_are_kept_with_the_recording_a_resume_must_share_them_and_the_card_makes_it_again(
    tmp_path, needs_vulkan
):
    out = tmp_path / "ak"
    options = (("close_steps", 8),)
    record(RecordConfig.of(AK, 1, out, control_mode="pd_joint_pos", policy_options=options, mcap=False), False)
    assert _settings(out)["expert_options"] == {"close_steps": 8}
    text = (out / "README.md").read_text()
    assert "the expert's settings `close_steps=8`" in text
    command = text.split("- Made again by: `")[1].split("`")[0]
    assert "--policy-option close_steps=8" in command
    again = tmp_path / "again"
    run = launch.run(
        [str(BIN / "kitbench"), *command.split()[1:-1], str(again), "--no-mcap"],
        capture_output=True,
        text=True,
        env=OFFLINE,
    )
    assert run.returncode == 0, run.stderr[-2000:]
    assert _settings(again)["expert_options"] == {"close_steps": 8}
    assert (_columns(again)["action"] == _columns(out)["action"]).all()
    # the other expert cannot continue it: its episodes would differ from what their seeds say
    resumed = RecordConfig.of(AK, 2, out, control_mode="pd_joint_pos", resume=True, mcap=False)
    with pytest.raises(ValueError, match=r"expert_options: recorded \{'close_steps': 8\}, asked None"):
        record(resumed, progress=False)
    # a conversion is made by the same expert
    converted = tmp_path / "converted"
    record(convert_config(out, converted, obs_mode="rgb", camera_size="32x32"), progress=False)
    assert _settings(converted)["expert_options"] == {"close_steps": 8}


def test_a_recipe_gives_options_as_a_table_or_as_command_line_pairs(tmp_path):
    recipe = tmp_path / "r.toml"
    base = f'task = "{AK}"\nepisodes = 1\nout = "o"\n'
    configs = []
    for form in ("{close_steps = 8, grasp_height = 0.02}", '["close_steps=8", "grasp_height=0.02"]'):
        recipe.write_text(base + f"policy_options = {form}\n")
        configs.append(load_recipe(recipe))
    assert configs[0].policy.policy_options == configs[1].policy.policy_options
    assert dict(configs[0].policy.policy_options) == {"close_steps": 8, "grasp_height": 0.02}
    recipe.write_text(base + "policy_options = 5\n")
    with pytest.raises(KitbenchError, match=r"policy_options is 5; give a table \(\{close_steps = 8\}\)"):
        load_recipe(recipe)


def test_command_line_options_add_to_a_recipes_key_by_key_for_its_own_policy(tmp_path):
    """`--policy-option K=V` on a recipe with `policy_options`: the recipe's others kept, the command line's value
    winning where both name one; for another policy, the recipe's (its expert's) are dropped."""
    recipe = tmp_path / "r.toml"
    recipe.write_text(
        f'task = "{AK}"\nepisodes = 1\nout = "o"\npolicy_options = {{close_steps = 8, grasp_height = 0.02}}\n'
    )
    config = load_recipe(recipe, policy_options=(("grasp_height", 0.03), ("turn_over_slot", True)))
    assert dict(config.policy.policy_options) == {"close_steps": 8, "grasp_height": 0.03, "turn_over_slot": True}
    assert dict(load_recipe(recipe).policy.policy_options) == {"close_steps": 8, "grasp_height": 0.02}
    named = load_recipe(recipe, policy="expert", policy_options=(("turn_over_slot", True),))  # the recipe's default
    assert dict(named.policy.policy_options) == {"close_steps": 8, "grasp_height": 0.02, "turn_over_slot": True}
    other = load_recipe(recipe, policy="random", policy_options=(("seed", 3),))
    assert dict(other.policy.policy_options) == {"seed": 3}


def _held_at(robot: str, options: dict | None, seed: int) -> tuple[float, float, bool, float]:
    """One LiftPegUpright episode of the expert: where along the peg's axis its TCP is as the hand closes (m, the
    sign dropped), the TCP's height as the peg first stands, whether it stood up, and the peg's centre above its
    standing height as the swing ends (m)."""
    from kitbench.geometry import quat_to_matrix

    env = gym.make("kitbench/LiftPegUpright-v1", obs_mode="state", control_mode="pd_joint_pos", robot_uids=robot)
    u = env.unwrapped
    try:
        obs, info = env.reset(seed=seed)
        expert = ExpertPolicy(options)
        expert.reset(env, seed, obs, info)
        along = swing_end = tcp_z = None
        for _ in range(u.max_episode_steps):
            phase = expert.phase
            obs, _, _, truncated, info = env.step(expert.act(obs))
            if along is None and expert.phase == "grasp":
                peg = u.peg.pose
                offset = quat_to_matrix(peg.q).T @ (u.robot.tcp_pose().p - peg.p)
                along = abs(float(offset[0]))
            if swing_end is None and phase == "swing" and expert.phase != "swing":
                swing_end = float(u.peg.pose.p[2]) - PEG_HALF_LENGTH * u.peg_scale
            if tcp_z is None and info["success"]:
                tcp_z = float(u.robot.tcp_pose().p[2])
            if truncated or expert.phase in ("release", "done"):
                break  # not at `terminated`: a peg that ends the swing low succeeds before the swing ends
        assert along is not None and swing_end is not None
        return along, tcp_z or 0.0, tcp_z is not None, swing_end
    finally:
        env.close()


@pytest.mark.parametrize(("robot", "spread"), [("panda", 0.02), ("so101", 0.3)])
def test_a_grasp_spread_holds_each_peg_where_its_seed_draws_and_sets_it_down_by_it(robot, spread):
    """`grasp_offset_spread`: demonstrations that hold the peg anywhere along it, as a learned grasp does."""
    seeds = range(4)
    fixed = [_held_at(robot, None, seed) for seed in seeds]
    spread_runs = [_held_at(robot, {"grasp_offset_spread": spread}, seed) for seed in seeds]
    assert all(success for _, _, success, _ in fixed + spread_runs)
    # without the option every grasp is at the config's one offset; with it, one per episode
    # (up to a few millimetres of slip on ManiSkill's peg material, 0.3)
    assert max(a for a, *_ in fixed) - min(a for a, *_ in fixed) < 0.003
    along = [a for a, *_ in spread_runs]
    assert max(along) - min(along) > 0.01
    # the hand stands the peg up higher or lower by where it holds it: the set-down follows the grasp
    heights = [h for _, h, _, _ in spread_runs]
    assert max(heights) - min(heights) > 0.005
    # the draw is the episode's: the same seed holds the peg at the same place
    assert _held_at(robot, {"grasp_offset_spread": spread}, 2)[0] == pytest.approx(along[2], abs=1e-6)


def test_a_negative_grasp_spread_is_one_line():
    env = gym.make("kitbench/LiftPegUpright-v1", obs_mode="state", robot_uids="so101")
    try:
        env.reset(seed=0)
        with pytest.raises(KitbenchError) as error:
            env.unwrapped.make_expert({"grasp_offset_spread": -0.1})
    finally:
        env.close()
    assert "grasp_offset_spread must be >= 0 (0: no spread), got -0.1" in str(error.value)
    assert "\n" not in str(error.value)


@pytest.mark.parametrize("robot", ["panda", "so101"])
def test_a_set_down_spread_ends_each_swing_at_its_seeds_height_and_the_table_ends_the_descent(robot):
    """`set_down_clearance_spread`: the swing leaves the upright peg 2-25 mm up, drawn per episode, and the hand
    lowers it until it stands on the table."""
    options = {"set_down_clearance": 0.0135, "set_down_clearance_spread": 0.0115}
    runs = [_held_at(robot, options, seed) for seed in range(4)]
    assert all(success for _, _, success, _ in runs)
    heights = [h for *_, h in runs]
    assert all(-0.002 < h < 0.029 for h in heights), heights
    assert max(heights) - min(heights) > 0.005, heights
    assert _held_at(robot, options, 2)[3] == pytest.approx(heights[2], abs=1e-6)


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"set_down_clearance_spread": -0.01}, "set_down_clearance_spread must be >= 0 (0: no spread), got -0.01"),
        ({"set_down_clearance_spread": 0.01}, "set_down_clearance_spread=0.01 reaches below the table"),
    ],
)
def test_a_set_down_spread_below_the_table_is_one_line(options, message):
    env = gym.make("kitbench/LiftPegUpright-v1", obs_mode="state", robot_uids="so101")
    try:
        env.reset(seed=0)
        with pytest.raises(KitbenchError) as error:
            env.unwrapped.make_expert(options)
    finally:
        env.close()
    assert message in str(error.value) and "\n" not in str(error.value)
