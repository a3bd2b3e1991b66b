"""Writes recorded episodes into a LeRobot v3 dataset that stock lerobot can load at any moment.

LeRobot leaves a dataset unloadable until `finalize()` (the data parquet has no footer and the episode index is
missing). So episodes are committed in sessions: a session works on a clone of the dataset folder (big files
hard-linked, metadata copied), adds episodes, finalizes, and then the clone replaces the published folder by
rename. A kill at any point leaves the published folder as it was at the last commit; `recover()` clears what a
killed session left behind.

Per-episode facts LeRobot has no place for (seed, success, task configuration) go to
`meta/kitbench_episodes.jsonl` (`kitbench.metadata`), written with the same commit, and to the `episode_seed`
column, whose feature entry carries the recording's settings through LeRobot's tools.
"""

from __future__ import annotations

import ctypes
import importlib
import os
import shutil
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from kitbench import faults
from kitbench.metadata import EpisodeInfo, RecordingInfo, read_episode_file, write_episodes
from kitbench.recording.card import write_card
from kitbench.recording.durable import fsync_dir, fsync_new
from kitbench.recording.layout import RETIRED_SUFFIX, SESSION_SUFFIX, beside, last_commit

__all__ = ["DatasetWriter", "recover"]


def _video_encoder():
    from lerobot.configs import RGBEncoderConfig

    # h264 decodes everywhere (torchcodec, PyAV, browsers) and encodes ~30% faster than the AV1 default here.
    return RGBEncoderConfig(vcodec="h264", crf=20, preset="veryfast", g=2)


def _depth_encoder():
    """LeRobot's lossless 12-bit HEVC depth stream, quantised as `kitbench.envs.features.DEPTH_ENCODING` says."""
    from lerobot.configs import DepthEncoderConfig

    from kitbench.envs.features import DEPTH_ENCODING

    return DepthEncoderConfig(**DEPTH_ENCODING)


def recover(root: Path) -> None:
    """Bring a folder left by a killed run back to its last commit."""
    root = Path(root)
    committed = last_commit(root)
    if committed is not None and committed != root:
        os.replace(committed, root)
    for leftover in (beside(root, SESSION_SUFFIX), beside(root, RETIRED_SUFFIX)):
        if leftover.exists():
            shutil.rmtree(leftover)


def remove_recording(root: Path) -> None:
    """Delete the recording at `root`: the dataset, what a killed commit left, and its journal (`--overwrite`)."""
    from kitbench.recording.journal import EpisodeJournal

    root = Path(root)
    recover(root)
    if root.exists():
        shutil.rmtree(root)
    EpisodeJournal(root).remove()


def _clone(src: Path, dst: Path) -> None:
    """Copy metadata, hard-link everything else (a session never rewrites existing data or video files)."""
    for path in src.rglob("*"):
        rel = path.relative_to(src)
        target = dst / rel
        if path.is_dir():
            target.mkdir(parents=True, exist_ok=True)
            continue
        target.parent.mkdir(parents=True, exist_ok=True)
        if rel.parts[0] == "meta":
            shutil.copy2(path, target)
        else:
            os.link(path, target)


AV_LOG_ERROR = 16  # libavutil/log.h


def quiet_video_logs() -> None:
    """The video encoder's per-file statistics and the per-episode table-mapping bars are noise next to our
    own progress bar; errors still show.

    PyAV's level alone does not hold: lerobot hands logging back to libav's own callback after every video
    file, and that one prints at libav's level (x264 statistics, muxer notes: 240 lines in `make demo`). So
    libav's level is set too, in every libavutil this process has loaded.
    """
    import av.logging

    import datasets

    av.logging.set_level(av.logging.ERROR)
    datasets.disable_progress_bars()  # type: ignore[attr-defined]  # exported by datasets' lazy __init__
    # lerobot wraps some table operations in a context that re-enables the bars on exit, after which every
    # episode but the first printed a "Map" bar. Pinning them off is what HF_DATASETS_DISABLE_PROGRESS_BARS=1
    # does when set before `datasets` is imported; enabling then only warns, which is silenced here. (The
    # module is looked up by name: `datasets.utils.tqdm` the attribute is its tqdm class.)
    tqdm_module: Any = importlib.import_module("datasets.utils.tqdm")
    tqdm_module.HF_DATASETS_DISABLE_PROGRESS_BARS = True
    warnings.filterwarnings("ignore", message="Cannot enable progress bars", category=UserWarning)
    try:
        with open("/proc/self/maps") as maps:
            libraries = {line.split()[-1] for line in maps if "/libavutil" in line}
    except OSError:  # not Linux: PyAV's level is all we can set
        return
    for path in libraries:
        ctypes.CDLL(path).av_log_set_level(AV_LOG_ERROR)


class DatasetWriter:
    """Adds whole episodes to a LeRobot dataset under `root`, committing them in sessions."""

    def __init__(self, root: Path, info: RecordingInfo, features: dict, robot_type: str, replace: bool = False):
        """`replace`: the first commit replaces the dataset at `root` whole (until then it stays as it was)."""
        self.root = Path(root)
        self.replace = replace
        self.info = info
        self.repo_id = info.repo_id or f"kitbench/{info.task}"
        self.fps = info.fps
        self.features = features
        self.robot_type = robot_type
        self._session: Any = None  # LeRobotDataset being written in the session folder (lerobot is untyped)
        self._pending: list[EpisodeInfo] = []  # kitbench metadata of episodes in the open session
        self._session_started = 0.0
        quiet_video_logs()

    # -- state of the published dataset ------------------------------------------------------------
    @property
    def session_root(self) -> Path:
        return self.root.with_name(self.root.name + SESSION_SUFFIX)

    # -- writing ---------------------------------------------------------------------------------
    def _open_session(self):
        from lerobot.datasets.lerobot_dataset import LeRobotDataset

        session = self.session_root
        if session.exists():
            shutil.rmtree(session)
        if self.root.exists() and not self.replace:
            _clone(self.root, session)
            self._session = LeRobotDataset.resume(
                self.repo_id, root=session, rgb_encoder=_video_encoder(), depth_encoder=_depth_encoder()
            )
        else:
            self._session = LeRobotDataset.create(
                self.repo_id,
                fps=self.fps,
                features=self.info.carry(self.features),
                root=session,
                robot_type=self.robot_type,
                use_videos=True,
                rgb_encoder=_video_encoder(),
                depth_encoder=_depth_encoder(),
            )
        self._session_started = time.monotonic()

    def add_episode(self, record) -> int:
        """Append one finished episode; returns its episode index in the dataset."""
        if self._session is None:
            self._open_session()
        ds = self._session
        index = ds.meta.total_episodes
        seed = np.array([record.seed], dtype=np.int64)
        half = len(record.frames) // 2
        for i, frame in enumerate(record.frames):
            if i == half:
                faults.point("writer.frames")
            ds.add_frame(
                {**{k: v for k, v in frame.items() if k in self.features}, "episode_seed": seed, "task": record.task}
            )
        ds.save_episode()
        faults.point("writer.saved")
        self._pending.append(
            EpisodeInfo(
                index,
                record.seed,
                record.success,
                record.length,
                record.first_success,
                record.task,
                record.config,
                record.teleop,
            )
        )
        return index

    def session_age(self) -> float:
        return time.monotonic() - self._session_started if self._session is not None else 0.0

    def commit(self) -> None:
        """Finalize the open session and publish it in place of the dataset folder."""
        if self._session is None:
            return
        self._session.finalize()
        self._session = None
        self.replace = False  # later sessions extend what this commit publishes
        faults.point("commit.finalized")
        session = self.session_root
        episodes = read_episode_file(session) + self._pending
        write_episodes(session, episodes)
        self.info.holding([e.seed for e in episodes]).write(session)
        faults.point("commit.metadata")
        write_card(session)
        fsync_new(session)  # durable before it is published: the journal forgets these episodes next
        faults.point("commit.card")
        retired = self.root.with_name(self.root.name + RETIRED_SUFFIX)
        if self.root.exists():
            os.replace(self.root, retired)
            faults.point("commit.retired")
        os.replace(session, self.root)
        fsync_dir(self.root.parent)
        faults.point("commit.swapped")
        if retired.exists():
            shutil.rmtree(retired)
        self._pending = []

    def abandon(self) -> None:
        """Drop the open session (its episodes were never published)."""
        self._session = None
        self._pending = []
        if self.session_root.exists():
            shutil.rmtree(self.session_root)
