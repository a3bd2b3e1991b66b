"""`lerobot-eval --env.type=kitbench --help` reads like lerobot's own env configs: a section named after the
config class, and a help line for each kitbench option saying what it takes."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import draccus
import numpy as np
import pytest
from lerobot.envs.configs import EnvConfig
from sapien import physx

from lerobot_env_kitbench.config import KitbenchEnvConfig
from lerobot_env_kitbench.env import LeRobotKitbenchEnv


@dataclass
class Top:
    """A command line with one `--env.*` group, as lerobot-eval's."""

    env: EnvConfig = field(default_factory=KitbenchEnvConfig)


def test_lerobot_eval_help_documents_every_kitbench_option():
    command = shutil.which("lerobot-eval", path=str(Path(sys.executable).parent))
    assert command, "lerobot-eval is installed with lerobot"
    done = subprocess.run(
        [command, "--env.type=kitbench", "--help"],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "HF_HUB_OFFLINE": "1", "COLUMNS": "200"},
    )
    assert done.returncode == 0, done.stderr[-2000:]
    text = done.stdout
    section = text[text.index("KitbenchEnvConfig ['env']:") :]
    section = section[: section.index("EvalConfig ['eval']:")]
    assert "<locals>" not in text
    flat = " ".join(section.split())  # argparse wraps help text under long option names
    lines = {"--env." + part.split()[0]: part for part in flat.split(" --env.")[1:]}
    for option, words in {
        "--env.task": "LiftPegUpright-v1 or AssemblingKits-v1",
        "--env.obs_type": "the obs mode the dataset was recorded in: rgbd, depth, segmentation",
        "--env.pointcloud_points": "Points per frame with obs_mode pointcloud",
        "--env.depth_unit": "lerobot-train's --dataset.depth_output_unit",
        "--env.control_mode": "a trained policy must act in the one its training dataset was recorded in",
        "--env.robot": "One of the task's robots",
        "--env.episode_length": "default: the task's own step limit",
        "--env.perturbations": "Robustness perturbations by name and level",
    }.items():
        assert words in lines[option], (option, lines[option])


def test_env_perturbations_parse_from_the_command_line_and_reach_the_env():
    parsed = draccus.parse(Top, args=["--env.type=kitbench", '--env.perturbations={"object_mass": 100}'])
    kwargs = parsed.env.gym_kwargs
    assert kwargs["perturbations"] == {"object_mass": 100}
    masses = []
    for extra in ({}, {"perturbations": kwargs["perturbations"]}):
        env = LeRobotKitbenchEnv("LiftPegUpright-v1", render_mode=None, **extra)
        env.reset(seed=0)
        peg = env.unwrapped._env.target_object
        masses.append(peg.find_component_by_type(physx.PhysxRigidDynamicComponent).mass)
    assert np.isclose(masses[1], 2 * masses[0])
    with pytest.raises(draccus.utils.ParsingError):
        draccus.parse(Top, args=["--env.type=kitbench", '--env.perturbations={"wind": 1}'])
