"""`FastReader`: stock `LeRobotDataset` samples, from memory.

lerobot builds the dataset `lerobot-train` trains on with `LeRobotDataset`, whose reader (`DatasetReader`) has no
configuration that avoids its per-sample costs: a `datasets` row read deep-copies the table's feature objects
(~2 ms each, three per sample with an action chunk), and the video decoder reopens and seeks the file for every
frame. `FastReader` subclasses that reader and, for a kitbench recording, answers `get_item` from numpy columns
and the frame cache instead; everything else (loading, metadata, the episode selection) stays lerobot's. The
samples are stock's, bit for bit: the same keys, dtypes, shapes and values, the image transforms called in the
same order on the same tensors (`tests/test_training_input.py`).

`install()` is the one place kitbench touches lerobot's internals: it makes `LeRobotDataset` build this reader,
and has a kitbench recording checked (`kitbench.integrity`) before lerobot reads its metadata, so a damaged file
is one line naming it rather than a traceback from pyarrow or a download attempt. The LeRobot plugin calls it
when lerobot imports it (`lerobot-train`, `lerobot-eval`). `KITBENCH_FAST_READER=0` keeps stock's reader.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from lerobot.configs import DEPTH_METER_UNIT
from lerobot.datasets import factory as dataset_factory, lerobot_dataset
from lerobot.datasets.dataset_metadata import LeRobotDatasetMetadata
from lerobot.datasets.dataset_reader import DatasetReader
from lerobot.datasets.depth_utils import MM_PER_METRE, dequantize_depth
from lerobot.datasets.io_utils import UINT16_PIL_MODES
from lerobot.datasets.video_utils import decode_video_frames

from kitbench.integrity import check_dataset
from kitbench.metadata import is_recording
from kitbench.training.columns import Columns, UnsupportedColumn
from kitbench.training.frames import FrameCache, Layout, cache_key, decode_jobs, open_or_build

log = logging.getLogger(__name__)

ENABLE = "KITBENCH_FAST_READER"
# The attributes of lerobot's `DatasetReader` that `Source` takes, by its field: most are private, which a lerobot
# release may move (FastReader also reads `_absolute_to_relative_idx` and `_image_transforms`);
# tests/test_lerobot_coupling.py compares every one with the installed lerobot.
READER_ATTRIBUTES = {
    "meta": "_meta",
    "root": "root",
    "hf_dataset": "hf_dataset",
    "episodes": "episodes",
    "delta_indices": "delta_indices",
    "video_backend": "_video_backend",
    "tolerance_s": "_tolerance_s",
    "return_uint8": "_return_uint8",
    "depth_output_unit": "_depth_output_unit",
    "depth_encoders": "_depth_encoder_configs",
    "image_depth_units": "_image_depth_units",
}
# Columns held per process: past this (point clouds of many episodes), stock's reader serves the dataset.
COLUMN_BUDGET = 1 << 30


def enabled() -> bool:
    return os.environ.get(ENABLE, "1") not in ("0", "false", "no", "off")


def is_kitbench_recording(root: Path) -> bool:
    return is_recording(root)


def install() -> None:
    """`LeRobotDataset` builds `FastReader` from now on, in this process and the loader workers it forks, and
    every kitbench recording lerobot opens is checked first."""
    lerobot_dataset.DatasetReader = FastReader  # lerobot looks the class up at each build
    # and the metadata class, in the two modules that build it for reading: `make_dataset` and `LeRobotDataset`
    lerobot_dataset.LeRobotDatasetMetadata = CheckedMetadata
    dataset_factory.LeRobotDatasetMetadata = CheckedMetadata


class CheckedMetadata(LeRobotDatasetMetadata):
    """lerobot's dataset metadata, read after `check_dataset` when the folder is a kitbench recording (a dataset
    that is not one, or not on disk, is lerobot's alone)."""

    def __init__(self, repo_id: str, root: str | Path | None = None, *args: Any, **kwargs: Any):
        if root is not None and (Path(root) / "meta").is_dir() and is_kitbench_recording(Path(root)):
            check_dataset(Path(root))
        super().__init__(repo_id, root, *args, **kwargs)


class FastReader(DatasetReader):
    def __init__(self, *args: Any, **kwargs: Any):
        super().__init__(*args, **kwargs)
        self._fast: _FastPath | None = None
        self._decided = False

    def try_load(self) -> bool:
        self._decided = False
        return super().try_load()

    def load_and_activate(self) -> None:
        self._decided = False
        super().load_and_activate()

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state["_fast"], state["_decided"] = None, False  # a spawned worker builds its own
        return state

    @property
    def fast(self) -> _FastPath | None:
        """What serves the samples from memory; None while lerobot's own `get_item` does (not decided yet, not a
        kitbench recording, switched off, or a column it does not hold)."""
        return self._fast

    def get_item(self, idx: int) -> dict:
        if not self._decided:
            self._fast = self._build_fast_path()
            self._decided = True
        if self._fast is None:
            return super().get_item(idx)
        return self._fast.item(int(idx), self._image_transforms)

    def _build_fast_path(self) -> _FastPath | None:
        if not enabled() or self.hf_dataset is None or not is_kitbench_recording(self.root):
            return None
        stock = {field: getattr(self, name) for field, name in READER_ATTRIBUTES.items()}
        source = Source(**{**stock, "root": Path(self.root)}, filtered=self._absolute_to_relative_idx is not None)
        try:
            return _FastPath(source)
        except UnsupportedColumn as exc:
            log.info("kitbench: %s read by lerobot's own reader (%s)", self.root, exc)
            return None


@dataclass(frozen=True)
class Source:
    """What a `DatasetReader` knows of its dataset, handed over by the reader itself."""

    meta: Any  # LeRobotDatasetMetadata
    root: Path
    hf_dataset: Any  # datasets.Dataset
    episodes: list[int] | None
    delta_indices: dict[str, list[int]] | None
    filtered: bool  # an episode selection: table rows are not absolute frame indices
    video_backend: str | None
    tolerance_s: float
    return_uint8: bool
    depth_output_unit: str
    depth_encoders: dict
    image_depth_units: dict


def _in_turn(jobs: list) -> Callable[[], None]:
    def run() -> None:
        for job in jobs:
            job()

    return run


class _FastPath:
    """One reader's dataset, held as columns and cached frames."""

    def __init__(self, source: Source):
        meta = source.meta
        hf = source.hf_dataset
        self.source = source
        self.names = list(hf.column_names)
        self.video_keys = list(meta.video_keys)
        self.image_keys = [key for key in meta.image_keys if key in self.names]
        self.depth_keys = set(meta.depth_keys)
        self.camera_keys = list(meta.camera_keys)
        table_names = [name for name in self.names if name not in self.image_keys]
        size = sum(hf.data.table.column(name).nbytes for name in table_names)
        if size > COLUMN_BUDGET:
            raise UnsupportedColumn(f"{size / 1e9:.1f} GB of columns")
        self.columns = Columns.from_table(hf.data.table, table_names)
        episodes = meta.episodes
        self.ep_from = np.asarray(episodes["dataset_from_index"], dtype=np.int64)
        self.ep_to = np.asarray(episodes["dataset_to_index"], dtype=np.int64)
        self.deltas = {k: np.asarray(v, dtype=np.int64) for k, v in (source.delta_indices or {}).items()}
        index = self.columns["index"]
        self.relative: np.ndarray | None = None
        if source.filtered:
            self.relative = np.full(int(index.max()) + 1, -1, dtype=np.int64)
            self.relative[index] = np.arange(len(index))
        self.tasks = [str(name) for name in meta.tasks.index]
        self.frames = self._frame_cache()

    # -- the frame cache ------------------------------------------------------------------------
    def _frame_cache(self) -> FrameCache | None:
        keys = self.video_keys + self.image_keys
        if not keys:
            return None
        source = self.source
        layout = Layout(len(self.columns["index"]), {key: self._frame_spec(key) for key in keys})
        episodes = None if source.episodes is None else sorted(int(e) for e in source.episodes)
        key = cache_key(source.root, episodes, source.video_backend, source.tolerance_s)
        return open_or_build(key, layout, self._fill, source.root)

    def _frame_spec(self, key: str) -> dict:
        height, width, channels = self.source.meta.features[key]["shape"]
        if key in self.video_keys:
            dtype = "uint16" if key in self.depth_keys else "uint8"
            return {"kind": "video", "dtype": dtype, "shape": [channels, height, width]}
        mode = self._image_mode(key)
        if mode not in ("RGB", "L", *UINT16_PIL_MODES):
            raise UnsupportedColumn(f"{key}: images of mode {mode}")
        dtype = "uint16" if mode in UINT16_PIL_MODES else "uint8"
        return {"kind": "image", "dtype": dtype, "shape": [1 if mode != "RGB" else 3, height, width], "mode": mode}

    def _image_mode(self, key: str) -> str:
        hf = self.source.hf_dataset
        assert hf is not None
        value = hf.data.table.column(key)[0].as_py()
        return hf.features[key].decode_example(value).mode

    def _fill(self, array_of) -> None:
        """Decode every row's frame of every camera feature into the arrays `array_of(key)` returns: one job per
        video file (lerobot's torchcodec decoders are cached per file and not thread-safe) and per image feature,
        each decoding its episodes in turn."""
        episode_index = self.columns["episode_index"]
        starts = np.flatnonzero(np.diff(episode_index, prepend=-1))
        bounds = list(zip(starts.tolist(), [*starts[1:].tolist(), len(episode_index)], strict=True))
        jobs = []
        for key in self.video_keys:
            target, files = array_of(key), self._video_files(key)
            by_file: dict[Path, list] = {}
            for start, stop in bounds:
                path, from_timestamp = files[int(episode_index[start])]
                by_file.setdefault(path, []).append(self._video_job(key, target, path, from_timestamp, start, stop))
            jobs += [_in_turn(parts) for parts in by_file.values()]
        for key in self.image_keys:
            jobs.append(_in_turn([self._image_job(key, array_of(key), start, stop) for start, stop in bounds]))
        decode_jobs(jobs)

    def _video_files(self, key: str) -> dict[int, tuple[Path, float]]:
        """Episode -> (its video file of `key`, where the episode starts in it), as `get_video_file_path` reads
        them, one column at a time (a row of lerobot's episode table costs a copy of its features)."""
        meta, prefix = self.source.meta, f"videos/{key}/"
        names = ["episode_index", f"{prefix}chunk_index", f"{prefix}file_index", f"{prefix}from_timestamp"]
        table = meta.episodes.select_columns(names).to_dict()
        return {
            int(episode): (
                self.source.root / meta.video_path.format(video_key=key, chunk_index=chunk, file_index=file),
                start,
            )
            for episode, chunk, file, start in zip(*(table[name] for name in names), strict=True)
        }

    def _video_job(self, key: str, target: np.ndarray, path: Path, from_timestamp: float, start: int, stop: int):
        source = self.source
        # the sum stock forms for each frame it decodes: a Python float plus the float32 timestamp
        shifted = [from_timestamp + float(ts) for ts in self.columns["timestamp"][start:stop]]

        def job() -> None:
            frames = decode_video_frames(
                path,
                shifted,
                source.tolerance_s,
                source.video_backend,
                return_uint8=True,
                is_depth=key in self.depth_keys,
            )
            target[start:stop] = frames.numpy()

        return job

    def _image_job(self, key: str, target: np.ndarray, start: int, stop: int):
        hf = self.source.hf_dataset
        assert hf is not None
        feature = hf.features[key]

        def job() -> None:
            values = hf.data.table.column(key).slice(start, stop - start).to_pylist()
            for offset, value in enumerate(values):
                array = np.asarray(feature.decode_example(value))
                target[start + offset] = array.transpose(2, 0, 1) if array.ndim == 3 else array[None]

        return job

    # -- one sample -----------------------------------------------------------------------------
    def _rows(self, absolute: np.ndarray) -> np.ndarray:
        return absolute if self.relative is None else self.relative[absolute]

    def _stacked(self, key: str, rows: np.ndarray) -> torch.Tensor:
        if key in self.image_keys:
            assert self.frames is not None
            return self.frames.images(key, rows)
        return self.columns.rows(key, rows)

    def item(self, idx: int, transforms: Callable | None) -> dict:
        """`DatasetReader.get_item(idx)`, step for step, with the reader's image transforms."""
        source, frames = self.source, self.frames
        row = self.columns.row(idx)
        item: dict[str, Any] = {}
        for name in self.names:
            item[name] = self._stacked(name, np.array([idx]))[0] if name in self.image_keys else row[name]
        episode, absolute = int(row["episode_index"]), int(row["index"])
        queried: dict[str, np.ndarray] = {}
        if self.deltas:
            start, stop = self.ep_from[episode], self.ep_to[episode]
            padding = {}
            for key, delta in self.deltas.items():
                wanted = absolute + delta
                queried[key] = self._rows(np.clip(wanted, start, stop - 1))
                padding[f"{key}_is_pad"] = torch.from_numpy((wanted < start) | (wanted >= stop))
            item = {**item, **padding}
            for key, rows in queried.items():
                if key not in self.video_keys:
                    item[key] = self._stacked(key, rows)
        if self.video_keys:
            assert frames is not None
            videos = {}
            for key in self.video_keys:
                rows = queried.get(key, np.array([idx]))
                clip = frames.video(key, rows, source.return_uint8 or key in self.depth_keys)
                if key in self.depth_keys:
                    encoder = source.depth_encoders[key]
                    clip = dequantize_depth(
                        clip,
                        depth_min=encoder.depth_min,
                        depth_max=encoder.depth_max,
                        shift=encoder.shift,
                        use_log=encoder.use_log,
                        output_unit=source.depth_output_unit,
                    )
                videos[key] = clip.squeeze(0)
            item = {**videos, **item}
        if transforms is not None:
            for key in self.camera_keys:
                if key not in self.depth_keys:
                    item[key] = transforms(item[key])
        for key, stored_unit in source.image_depth_units.items():
            if key in item and stored_unit is not None and stored_unit != source.depth_output_unit:
                item[key] = item[key] * MM_PER_METRE if stored_unit == DEPTH_METER_UNIT else item[key] / MM_PER_METRE
        item["task"] = self.tasks[int(row["task_index"])]
        return item
