"""`kitbench merge`: one dataset from recordings of disjoint seed ranges (shards), through LeRobot's own
aggregation (`lerobot.datasets.aggregate`), with kitbench's per-episode metadata and MCAP logs carried along.

Shards are how recording scales past one writer: several `kitbench record` runs (on several machines, each with
its own workers) record consecutive seed ranges, and the merge concatenates them. The result is the recording
one run over all the seeds would have made: the same frames, indices, episode metadata and MCAP logs (tested
frame for frame, video frames decoded). Shards are merged in seed order whatever order they are given in; each
must be a finished recording with the same settings (all but the first seed). The merged dataset is built in a
temporary folder beside `out` and renamed into place, so a failure leaves nothing half-written.
"""

from __future__ import annotations

import dataclasses
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

from kitbench import faults
from kitbench.config.declare import setting
from kitbench.errors import KitbenchError
from kitbench.integrity import check_dataset
from kitbench.metadata import CARRIER, EpisodeInfo, RecordingInfo, lerobot_info, read_episodes, write_episodes
from kitbench.recording.card import write_card
from kitbench.recording.config import check_repo_id
from kitbench.recording.dataset import recover
from kitbench.recording.layout import SESSION_SUFFIX, beside, journal_root
from kitbench.recording.session import MCAP_DIR

MERGING_SUFFIX = ".merging"
# Settings a recording stores that may differ between shards: where it started.
PER_SHARD = ("seed",)


@dataclass
class MergeSettings:
    # The dataset folders of finished recordings with the same settings.
    shards: tuple[Path, ...] = setting(positional=True)
    # The merged dataset's folder (new, or replaced with --overwrite).
    out: Path = setting(required=True)
    # Replace an existing --out.
    overwrite: bool = setting(False)
    # The merged dataset's repo id (default: the shards').
    repo_id: str | None = setting(None)


@dataclass
class Shard:
    root: Path
    info: RecordingInfo
    episodes: list[EpisodeInfo]

    @property
    def seeds(self) -> list[int]:
        return [e.seed for e in self.episodes]


def _read_shard(root: Path, finished: bool) -> Shard:
    """The recording at `root`; `finished`: refuse one a recording is still adding to (a journal or session beside
    it), which a merge would copy half of."""
    root = Path(root)
    if not root.is_dir():
        raise KitbenchError(f"shard {root} does not exist (give the folders of finished kitbench recordings)")
    if finished and (journal_root(root).is_dir() or beside(root, SESSION_SUFFIX).exists()):
        raise KitbenchError(f"shard {root} is an unfinished recording; finish it with kitbench record --resume")
    check_dataset(root)
    info = RecordingInfo.require(root, f"shard {root}").require_current(root)
    episodes = read_episodes(root)
    if not episodes:
        raise KitbenchError(f"shard {root} has no episodes")
    return Shard(root, info, episodes)


def _comparable(entry: dict | None) -> dict | None:
    """A feature's entry as LeRobot's merge compares it: a video's encoder settings may differ."""
    if entry is None or entry.get("dtype") != "video":
        return entry
    return {k: v for k, v in entry.items() if k != "info"}


def _check_shards(shards: list[Shard]) -> None:
    first = shards[0]
    for shard in shards[1:]:
        for key, (a, b) in first.info.differences(shard.info, ignore=PER_SHARD).items():
            raise KitbenchError(
                f"shards {first.root} and {shard.root} were recorded with different {key} ({a!r} and {b!r}); "
                "only the seed may differ"
            )
    features = lerobot_info(first.root).get("features", {})
    for shard in shards[1:]:
        theirs = lerobot_info(shard.root).get("features", {})
        for name in sorted(set(features) | set(theirs)):
            if name != CARRIER and _comparable(features.get(name)) != _comparable(theirs.get(name)):
                raise KitbenchError(f"shards {first.root} and {shard.root} store feature {name} differently")
        if features.get(CARRIER) != theirs.get(CARRIER):
            older = shard.root if "info" not in theirs.get(CARRIER, {}) else first.root
            raise KitbenchError(
                f"shard {older} was recorded before kitbench carried its settings in its features; "
                "merge it only with recordings made before"
            )
    owner: dict[int, Path] = {}
    for shard in shards:
        for seed in shard.seeds:
            if seed in owner:
                raise KitbenchError(f"seed {seed} is in both {owner[seed]} and {shard.root}; shards must not overlap")
            owner[seed] = shard.root


def _check_out(out: Path, shards: list[Shard], overwrite: bool) -> None:
    resolved = out.resolve()
    for shard in shards:
        root = shard.root.resolve()
        if resolved == root or root in resolved.parents or resolved in root.parents:
            raise KitbenchError(f"--out {out} overlaps shard {shard.root}; give a new folder")
    if (out.exists() or out.is_symlink()) and not overwrite:
        raise KitbenchError(f"output folder {out} exists; pass --overwrite to replace it")
    if out.exists() and not out.is_dir():
        raise KitbenchError(f"output {out} is a file; --out must be a folder")


def _link_or_copy(src: Path, dst: Path) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.link(src, dst)  # the shards' logs are never rewritten: a link is a copy that costs nothing
    except OSError:
        shutil.copy2(src, dst)


@dataclass
class MergeSummary:
    out: Path
    shards: int
    episodes: int
    frames: int
    without_logs: dict[Path, int] = dataclasses.field(default_factory=dict)  # shard -> episodes without MCAP logs

    def lines(self) -> list[str]:
        lost = [
            f"no MCAP log for {n} episode(s) of {root} (LeRobot's dataset tools do not copy mcap/); merged without"
            for root, n in self.without_logs.items()
        ]
        return [
            f"dataset: {self.out}",
            f"merged {self.shards} shards: {self.episodes} episodes, {self.frames} frames",
            *lost,
        ]


def merge(
    shard_roots: list[Path], out: Path, overwrite: bool = False, repo_id: str | None = None, finished: bool = True
) -> MergeSummary:
    """Merge finished recordings `shard_roots` into a new dataset at `out` (see the module docstring).
    `finished=False` is for the sharded recorder, which merges the dataset it is itself extending."""
    from lerobot.datasets.aggregate import aggregate_datasets

    from kitbench.recording.dataset import quiet_video_logs

    if len(shard_roots) < 2:
        raise KitbenchError(f"merge needs at least two recordings, got {len(shard_roots)}")
    if len({Path(r).resolve() for r in shard_roots}) != len(shard_roots):
        raise KitbenchError("a shard is given twice")
    if repo_id is not None:
        check_repo_id(repo_id)
    out = Path(out)
    recover(out)  # a merge a kill interrupted between its two renames: the dataset it was replacing back in place
    shards = sorted((_read_shard(r, finished) for r in shard_roots), key=lambda s: min(s.seeds))
    _check_shards(shards)
    _check_out(out, shards, overwrite)
    first = shards[0].info
    repo_id = repo_id or first.repo_id or f"kitbench/{first.task}"
    info = dataclasses.replace(first, repo_id=repo_id, seeds=None)  # the merged seeds are listed once known
    quiet_video_logs()
    staging = out.with_name(out.name + MERGING_SUFFIX)
    if staging.exists():
        shutil.rmtree(staging)  # what a killed merge left
    try:
        aggregate_datasets(
            [s.info.repo_id or repo_id for s in shards],
            repo_id,
            roots=[s.root for s in shards],
            aggr_root=staging,
        )
        faults.point("merge.aggregated")
        episodes, offset = [], 0
        without_logs: dict[Path, int] = {}
        for shard in shards:
            for episode in shard.episodes:
                index = episode.episode_index
                log = shard.root / MCAP_DIR / f"episode_{index:06d}.mcap"
                if log.is_file():
                    _link_or_copy(log, staging / MCAP_DIR / f"episode_{offset + index:06d}.mcap")
                else:
                    without_logs[shard.root] = without_logs.get(shard.root, 0) + 1
                episodes.append(dataclasses.replace(episode, episode_index=offset + index))
            offset += len(shard.episodes)
        if len(without_logs) == len(shards):  # recorded without logs (--no-mcap): nothing was lost
            without_logs = {}
        write_episodes(staging, episodes)
        info.holding([e.seed for e in episodes]).write(staging)
        write_card(staging)
        retired = out.with_name(out.name + ".retired")
        if out.exists():
            os.replace(out, retired)  # the old dataset stays whole until the new one is in place
            faults.point("merge.retired")
        os.replace(staging, out)
        shutil.rmtree(retired, ignore_errors=True)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return MergeSummary(out, len(shards), len(episodes), sum(e.length for e in episodes), without_logs)
