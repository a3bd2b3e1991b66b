"""The dataset card (`README.md`) written with every kitbench dataset, so a dataset pushed to the Hub explains itself.

Built with LeRobot's own card (`lerobot.datasets.utils.create_lerobot_dataset_card`: its YAML header, tags, template
and `meta/info.json` section), with kitbench's description: the task and its instructions, the robot, every stored
feature with its shape and units, the control mode, the episodes and their success, how the data was made and the
`kitbench record` command that makes it again. Rewritten at every commit from the dataset's own files, so it always
describes what is there.
"""

from __future__ import annotations

import json
import os
import shlex
from pathlib import Path

from kitbench.envs.features import CAMERA_PARAMS, ENVIRONMENT_STATE, POINTCLOUD_PREFIX, SENSOR_PARAM, STATE, modality
from kitbench.envs.modalities import texture_of
from kitbench.metadata import EPISODES_FILE, IDENTITY, RECORDING_FILE, RecordingInfo, read_episodes
from kitbench.teleop.checks import is_teleop

CARD = "README.md"
# What each kind of feature holds, beyond its dtype and shape (`kitbench.envs.features`).
UNITS = {
    "observation.state": "arm joint positions (rad), gripper opening (m), then any body joints and base pose",
    "observation.environment_state": "object and goal poses (m; quaternions w, x, y, z) and the task's fields",
    "action": "the policy's action in the control mode, as ManiSkill 3.0.1 has it (delta modes in [-1, 1], 1 being "
    "0.1 rad or m; rotations XYZ Euler; after the arm the gripper, -1 closed .. 1 open)",
    "executed_action": "what the robot executed: `action` plus any recording noise",
    "commanded_ee_pose": "the controller's TCP target, base frame (m; quaternion w, x, y, z)",
}


# What each point cloud feature holds (`observation.pointcloud.<part>`).
POINTCLOUD_PARTS = {
    "xyz": "point positions, world frame, metres",
    "rgb": "point colours",
    "segmentation": "segmentation id per point (the id-to-name table is in meta/info.json)",
}


def _describe(name: str, robot: str | None = None) -> str:
    """What feature `name` holds; the state's and the action's units are the robot's (`RobotSpec.units`)."""
    from kitbench.robots import ROBOTS

    units = ROBOTS[robot].units if robot in ROBOTS else None
    if units is not None and name == STATE and units.state_text:
        return units.state_text
    if units is not None and name == "action" and units.action_text:
        return units.action_text
    if name in UNITS:
        return UNITS[name]
    if name.startswith(POINTCLOUD_PREFIX):
        return POINTCLOUD_PARTS.get(name[len(POINTCLOUD_PREFIX) :], "")
    if name.startswith(SENSOR_PARAM):
        param = CAMERA_PARAMS.get(name.rsplit(".", 1)[-1])
        return "" if param is None else param.description
    texture = texture_of(name)
    return "" if texture is None else texture.description


def camera_notes(features: dict) -> list[str]:
    """The card's lines on the cameras' parameters: where they are and, with depth, how a pixel makes a world point
    (none for a dataset without them)."""
    if not any(name.startswith(SENSOR_PARAM) for name in features):
        return []
    note = (
        f"- Cameras: `{SENSOR_PARAM}<camera>.*` hold each camera's parameters in every frame, under ManiSkill's names "
        "and conventions (a camera on the robot moves with it), each matrix stored row by row: `.reshape(3, 3)`, "
        "`(3, 4)`, `(4, 4)` give them back (`info.matrix` in meta/info.json)."
    )
    if any(modality(name) == "depth" for name in features):
        note += (
            " A pixel (column, row) of `observation.images.<camera>_depth` with depth d (metres along the viewing "
            "axis, 0: nothing seen; stored in metres, returned by stock `LeRobotDataset` in millimetres unless "
            '`depth_output_unit="m"`) is the world point `cam2world_gl @ [d (u - cx) / fx, -d (v - cy) / fy, -d, 1]`, '
            "u = column + 0.5, v = row + 0.5, fx, fy, cx, cy from `intrinsic_cv`."
        )
    return [note]


# An entry of `observation.state` or `observation.environment_state` whose standard deviation over the whole
# dataset is below this (rad or m) is a joint the robot holds still, measured with its servo jitter, or a constant
# of the task (AssemblingKits' goal height once was: std 7e-6, the rounding of lerobot's statistics). LeRobot's
# MEAN_STD normalisation divides by that spread: on Fetch's LiftPegUpright data (head, torso and base held, std
# 7e-6 to 2.6e-4) a trained ACT saw those entries at up to 5,464 standard deviations once it drove the robot
# itself, and scored 8%; with the state left unnormalised, the same data, config and steps scored 80%
# (docs/learnability.md). A constant is harmless until anything (the `obs_noise` perturbation, a sensor) moves it.
STILL_STD = 1e-3

# The state vectors the card checks, with the lerobot feature type that a config's normalization_mapping names.
STILL_CHECKED = {STATE: "STATE", ENVIRONMENT_STATE: "ENV"}


def held_still(names: list[str], std: list[float], scales: list[float] | None = None) -> list[str]:
    """The names whose standard deviation is below `STILL_STD` (times each entry's unit per radian or metre,
    `scales`: the SO-101's degrees and gripper percent): the entries a robot (or the task) holds still."""
    scales = scales or [1.0] * len(names)
    return [name for name, value, k in zip(names, std, scales, strict=True) if value < STILL_STD * k]


def still_entries(root: Path, info: dict) -> dict[str, list[str]]:
    """Per state vector of `STILL_CHECKED`, the entries that the dataset at `root` (its `meta/info.json` read as
    `info`) holds still; vectors with none are left out. Reads `meta/stats.json` once."""
    stats_path = root / "meta" / "stats.json"
    if not stats_path.is_file():
        return {}
    stats = json.loads(stats_path.read_text())
    from kitbench.robots import ROBOTS

    robot = ROBOTS.get(info.get("robot_type") or "")
    found = {}
    for key in STILL_CHECKED:
        std = stats.get(key, {}).get("std")
        names = info["features"].get(key, {}).get("names") or []
        scales = robot.units.state_scales(robot) if robot is not None and key == STATE else None
        if scales is not None and len(scales) != len(names):
            scales = None
        if std is not None and len(names) == len(std) and (still := held_still(names, std, scales)):
            found[key] = still
    return found


def record_command(recording: RecordingInfo, episodes: int) -> str:
    """The command that makes this dataset again: the one it was made by when kitbench stored it (`kitbench eval
    --save-dataset`), else `kitbench record` (or `kitbench convert` for a conversion) with every setting that
    differs from its default as a flag."""
    from kitbench.config.declare import leaves
    from kitbench.config.flags import flag_of
    from kitbench.recording.config import RecordConfig

    if recording.made_by:
        return recording.made_by
    declared = leaves(RecordConfig)
    always: tuple[str, ...] = ("seed", "obs_mode", "control_mode", "policy")
    names: tuple[str, ...]
    if recording.source:
        always = ("obs_mode", "control_mode")
        flags = ["kitbench", "convert", recording.source]
        names = ("obs_mode", "control_mode", "pointcloud_points", "rgb_storage")
    else:
        flags = ["kitbench", "record", "--task", recording.task, "--episodes", str(episodes)]
        names = tuple(n for n in IDENTITY if n in declared and n != "task")
    for name in names:
        value = getattr(recording, name)
        leaf = declared[name]
        if value is None or (name not in always and value == leaf.default):
            continue
        if value is True:
            flags.append(flag_of(leaf))
        elif isinstance(value, list | tuple):
            flags += [flag_of(leaf), ",".join(map(str, value))]
        elif value is not False:
            flags += [flag_of(leaf), str(value)]
    if not recording.source:
        for key, value in {**(recording.expert_options or {}), **(recording.teleop_options or {})}.items():
            flags += ["--policy-option", f"{key}={_option_text(value)}"]
    return shlex.join([*flags, "--out", "<folder>"])


def _option_text(value) -> str:
    """A `--policy-option` value as the flag reads it back (JSON, else text): a port stays `/dev/ttyACM0`."""
    if isinstance(value, str):
        try:
            json.loads(value)
        except ValueError:
            return value  # text that reads back as itself
    return json.dumps(value)


def _teleop_note(recording: RecordingInfo, robot: str, fps: int) -> list[str]:
    """The card's line on a person's episodes: no step limit while recording, the suite's when scored."""
    if not is_teleop(recording.policy):
        return []
    from kitbench.registration import TASKS

    entry = TASKS.get(recording.task)
    seconds = (recording.teleop_options or {}).get("max_seconds")
    limit = "no time limit" if seconds is None else f"at most {seconds} s each (`max_seconds`)"
    scored = ""
    if entry is not None:
        steps = entry.env_class.episode_steps(robot)
        scored = f" ({steps} steps, {steps / fps:g} s)"
    line = (
        f"- Time: each episode ran until the person ended it or {recording.settle_steps} steps past success, "
        f"{limit}; how each ended (`key`, `button`, `success`, `limit`), its values clipped to the joint limits and "
        f"its steps held to the joint speeds are its `teleop` entry in `{EPISODES_FILE}`. `kitbench eval --policy "
        f"replay:<this dataset>` scores the episodes under the task's own step limit{scored}: one longer than that "
        "is scored where it stood at the limit."
    )
    return [line]


def _variant_note(task: str, robot: str) -> list[str]:
    """The card's line on the task's build for this robot where it is not the reference build (TabletopEnv.
    variant_description)."""
    from kitbench.registration import TASKS

    entry = TASKS.get(task)
    variant = None if entry is None else entry.env_class.variant_description(robot)
    return [] if variant is None else [f"- The task as built for the {robot}: {variant}."]


def card_text(root: Path) -> str:
    """The card of the dataset at `root` (its meta/info.json, kitbench's recording settings and episodes)."""
    from lerobot.datasets.utils import create_lerobot_dataset_card

    info = json.loads((root / "meta" / "info.json").read_text())
    recording = RecordingInfo.require(root)
    episodes = read_episodes(root)
    features = info["features"]
    stored = [n for n in features if n.startswith("observation.") or n in UNITS]
    successes = sum(bool(e.success) for e in episodes)
    seeds = sorted(e.seed for e in episodes)
    instructions = sorted({e.task for e in episodes if e.task})
    robot = info.get("robot_type") or recording.robot or "?"
    table = ["| feature | dtype | shape | what |", "|---|---|---|---|"]
    table += [
        f"| `{n}` | {features[n]['dtype']} | {tuple(features[n]['shape'])} | {_describe(n, robot)} |" for n in stored
    ]
    made = [f"policy `{recording.policy}`"]
    if is_teleop(recording.policy):
        device = recording.policy.partition(":")[2]
        made = [f"a person at the controls, with LeRobot's `{device}` teleoperator (policy `{recording.policy}`)"]
    if recording.expert_options:
        settings = ", ".join(f"`{k}={json.dumps(v)}`" for k, v in recording.expert_options.items())
        made.append(f"the expert's settings {settings} (its planner's defaults otherwise)")
    if recording.source:
        made.append(f"converted from `{recording.source}` (its executed actions replayed from each seed)")
    if recording.label:
        made.append(f"actions labelled by `{recording.label}` (the policy's own in `executed_action`)")
    if recording.action_noise:
        phases = recording.noise_phases
        made.append(f"action noise {recording.action_noise}" + (f" in phases {', '.join(phases)}" if phases else ""))
    if recording.settle_steps:
        made.append(f"{recording.settle_steps} steps recorded past each success")
    if recording.only_success:
        made.append("successful episodes only")
    seed_range = f"{seeds[0]}–{seeds[-1]}" if seeds else "–"
    heading = (
        f"A kitbench simulation dataset of **{recording.task}** with the **{robot}** robot, recorded at "
        f"{info['fps']} fps in control mode **`{recording.control_mode}`** with observations "
        f"**`{recording.obs_mode}`**."
    )
    made.append(f"reward `{recording.reward_mode}`")
    how = f"{', '.join(made)}; kitbench {recording.kitbench_version or '?'}"
    files = (
        f"Per-episode seed, success and task configuration: `{EPISODES_FILE}`; the recording's settings: "
        f"`{RECORDING_FILE}`; one MCAP log per episode (Foxglove) in `mcap/` when recorded."
    )
    held = [
        f"- Held still: `{key}` entries {', '.join(f'`{name}`' for name in still)} vary by less than "
        f"{STILL_STD:g} (std) over the whole dataset. Normalising them by mean and std (LeRobot's MEAN_STD) turns "
        "their jitter into inputs of hundreds of standard deviations when a policy drives the robot: train with "
        f'`"normalization_mapping": {{"{STILL_CHECKED[key]}": "IDENTITY"}}` or leave them out.'
        for key, still in still_entries(root, info).items()
    ]
    description = "\n".join(
        [
            heading,
            "",
            f"- Instructions: {'; '.join(f'“{t}”' for t in instructions) or '–'}",
            f"- Episodes: {len(episodes)} ({info['total_frames']} frames), {successes} successful; seeds {seed_range}",
            f"- Made by: {how}",
            f"- Made again by: `{record_command(recording, len(episodes))}`",
            *_variant_note(recording.task, robot),
            *_teleop_note(recording, robot, info["fps"]),
            *held,
            *camera_notes(features),
            f"- {files}",
            "",
            *table,
        ]
    )
    modalities = sorted({m for m in map(modality, features) if m is not None})
    structure = f"[meta/info.json](meta/info.json):\n```json\n{json.dumps(info, indent=4)}\n```\n"
    card = create_lerobot_dataset_card(
        tags=["kitbench", "simulation", recording.task, robot, *modalities],
        license="apache-2.0",
        repo_id=recording.repo_id,
        dataset_description=description,
        dataset_structure=structure,
    )
    return str(card)


def write_card(root: Path) -> None:
    """Write `root`/README.md from the dataset's files. Written aside and renamed over: a session folder's README
    is a hard link to the published one (`dataset._clone`), which must not change before the session commits."""
    path = Path(root) / CARD
    partial = path.with_name(f".{CARD}.partial")
    partial.write_text(card_text(Path(root)))
    os.replace(partial, path)
