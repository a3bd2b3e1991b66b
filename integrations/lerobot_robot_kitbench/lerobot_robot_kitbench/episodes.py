"""What each episode lerobot-record stores on the simulated arm was: its seed, whether and when it succeeded, how it
ended, its clipped values and rate-limited steps (as a person's episodes in `kitbench record` say them), in
kitbench's own episode file beside LeRobot's metadata (`meta/kitbench_episodes.jsonl`, one
`kitbench.metadata.EpisodeInfo` line per saved episode, read back by `kitbench.metadata.read_episodes`).

LeRobot has no clean place for them: lerobot-record turns every float a robot observes into a column of
`observation.state` (`hw_to_dataset_features`), which a policy then reads as input, and its episode metadata has
fixed columns. A line is written once LeRobot has saved its episode (a re-recorded one never is).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from kitbench.metadata import EpisodeInfo, read_episode_file, write_episodes


@dataclass
class Take:
    """One run of a dataset episode (re-recording it starts another)."""

    index: int  # LeRobot's episode index
    seed: int
    config: dict  # the task's episode configuration and the modes
    frames: int = 0  # frames LeRobot recorded (one observation each)
    steps: int = 0  # simulation control steps
    first_success: int | None = None  # the frame whose action led to the first success
    success_at_end: bool = False
    clipped: int = 0  # goal values beyond the simulated joints' ranges, clipped to them
    limited_steps: int = 0  # steps where a joint's speed limit held the arm back

    def info(self, ended: dict[str, str]) -> EpisodeInfo:
        """Its line, the episode having ended as `ended` says (the instruction is LeRobot's, read from its task
        index)."""
        person = {**ended, "clipped": self.clipped, "rate_limited": self.limited_steps}
        person |= {"success_at_end": self.success_at_end, "sim_steps": self.steps}
        return EpisodeInfo(
            episode_index=self.index,
            seed=self.seed,
            success=self.first_success is not None,
            length=self.frames,
            first_success=self.first_success,
            config=self.config,
            teleop=person,
        )


class EpisodeFile:
    """The episode file of the dataset at `root`, with the lines it already has (`--resume`)."""

    def __init__(self, root: Path, saved: Callable[[], int]):
        self.root, self.saved = root, saved
        self.lines = read_episode_file(root)
        self.pending: EpisodeInfo | None = None

    def ended(self, episode: EpisodeInfo) -> None:
        """An episode's loop ended: its line waits until LeRobot saves it."""
        self.settle()
        self.pending = episode

    def settle(self) -> None:
        """Write the pending line if LeRobot saved its episode since (else it was re-recorded: dropped)."""
        pending, self.pending = self.pending, None
        if pending is not None and self.saved() > pending.episode_index and pending.length > 0:
            self.lines = [e for e in self.lines if e.episode_index != pending.episode_index] + [pending]
            write_episodes(self.root, self.lines)
