"""`--robot.type=kitbench_so101`: the config of the simulated SO-101 as a LeRobot robot.

Defined at module level so that every process that builds it registers the same choice class on import. Each
setting is checked as kitbench checks its own (one line naming the bad value and the valid choices); the comment
above each field is its `--help` text.
"""

from __future__ import annotations

from dataclasses import dataclass

from lerobot.robots import RobotConfig

from kitbench.config.checks import non_negative_int, optional, positive_int, seed
from kitbench.env_settings import TaskSettings, canonical_size
from kitbench.errors import KitbenchError, check_choice
from kitbench.registration import task_entry
from kitbench.teleop.options import TeleopOptions
from kitbench.teleop.view import has_display

ROBOT = "so101"
OBS_MODES = ("rgb", "state")
# The task a config that names none runs (lerobot builds a default config for `--robot.type=kitbench_so101 --help`).
DEFAULT_TASK = "LiftPegUpright-v1"


@RobotConfig.register_subclass("kitbench_so101")
@dataclass
class KitbenchSO101Config(RobotConfig):
    # The kitbench task the simulated arm works on (one the SO-101 supports, as `kitbench record --task`).
    task: str = DEFAULT_TASK
    # rgb: the front and wrist cameras' images, as a real SO-101 station's; state: the motors only.
    obs_mode: str = "rgb"
    # Each camera's image, WIDTHxHEIGHT or one side (default: 128x128, kitbench's recordings').
    camera_size: str | None = None
    # The first scene's seed; each new scene takes the next, so a session meets the scenes a recording does.
    seed: int = 0
    # Outside lerobot-record's episodes (lerobot-teleoperate, lerobot-rollout): control steps a scene runs on
    # after its first success before it resets itself.
    settle_steps: int = 10
    # Outside lerobot-record's episodes: control steps after which a scene resets itself (default: the task's step
    # limit for the SO-101).
    episode_length: int | None = None
    # In lerobot-record's episodes: the arm waits at the start pose until every arm joint of the leader is within
    # this many degrees of it, as `kitbench record` waits (0: it follows at once).
    align: float = TeleopOptions.align
    # Step the simulation at the task's control rate in wall-clock time whatever the caller's loop rate (at most
    # one step per send_action); false: one step per send_action.
    realtime: bool = True
    # A SAPIEN viewer window on the scene (where a display exists), beside lerobot's Rerun view (--display_data).
    viewer: bool = False
    # As the real follower's: the largest move of a motor's goal from its present position per action (degrees or
    # gripper percent); default: no cap.
    max_relative_target: float | None = None

    def __post_init__(self):
        super().__post_init__()
        task_entry(self.task)  # an unknown task is one line naming the registered ones
        settings = TaskSettings(task=self.task, robot=ROBOT, control_mode="pd_joint_pos")
        settings.check_robot()  # so is a task without the SO-101
        self.task = settings.task_id
        check_choice("obs_mode", self.obs_mode, OBS_MODES)
        self.camera_size = canonical_size(self.camera_size)
        seed("seed", self.seed)
        non_negative_int("settle_steps", self.settle_steps)
        optional(positive_int)("episode_length", self.episode_length)
        if isinstance(self.align, bool) or not isinstance(self.align, int | float) or not self.align >= 0:
            raise KitbenchError(f"align must be a number of degrees >= 0, got {self.align!r}")
        if self.viewer and not has_display():
            raise KitbenchError(
                "viewer=true needs a display (DISPLAY is unset); without one, lerobot's own view can stream to a "
                "Rerun server elsewhere (--display_data=true --display_ip=... --display_port=...)"
            )
        target = self.max_relative_target
        if target is not None and not (isinstance(target, int | float) and target > 0):
            raise KitbenchError(f"max_relative_target must be a number > 0 (or unset), got {target!r}")
