"""Whether a dataset folder reads whole: `check_dataset` before anything reads or extends one.

kitbench never leaves a half-written file in a dataset folder (commits are renames), so what this finds was done
to the folder afterwards: a file truncated, deleted or edited by hand, a copy that stopped half-way. Every reader
of a dataset (`record --resume`, `convert`, `eval --policy replay:`, `view`, `merge`, and the training reader in
`lerobot-train`) calls it first, so damage is one line naming the file and what to do, before anything is read
at length or written, not a traceback from deep inside pyarrow, or a sample read from the wrong frame.

What it reads: every metadata file whole, each data file's footer and its index columns, each video file's last
frame, and the facts LeRobot and kitbench both keep, compared (episode counts and ranges, frame rate against the
timestamps, features against the data files' schema, kitbench's settings against those the `episode_seed`
feature carries, each episode's seed, length and success against its columns, and kitbench's episode file
against the digest written with it). Milliseconds for a state recording; a video file costs one decoded frame.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from kitbench import lerobot_schema
from kitbench.errors import KitbenchError, one_line
from kitbench.metadata import (
    CARRIER,
    EPISODES_FILE,
    INFO_FILE,
    RECORDING_FILE,
    EpisodeInfo,
    RecordingInfo,
    carried_settings,
    episodes_digest,
    features_digest,
)

TASKS_FILE = "meta/tasks.parquet"
STATS_FILE = "meta/stats.json"
EPISODES_DIR = "meta/episodes"
CODEBASE_VERSION = "v3.0"
# Columns every LeRobot v3 data file has, read to check where each frame belongs.
INDEX_COLUMNS = ("index", "episode_index", "frame_index", "timestamp", "task_index")
RESTORE = "restore it from a copy, or record the dataset again"


class Damage(KitbenchError):
    """A dataset file that does not read whole, or disagrees with the rest of the folder: `path`, `problem`, and
    what to do about it."""

    def __init__(self, path: Path, problem: str, remedy: str = RESTORE):
        super().__init__(f"{path}: {problem}; {remedy}")
        self.path, self.problem, self.remedy = path, problem, remedy


def check_dataset(root: str | Path) -> None:
    """Raise `Damage` (one line: the file, what is wrong, what to do) unless the LeRobot dataset at `root` and
    kitbench's files in it read whole and agree with each other."""
    root = Path(root)
    if not root.is_dir():
        raise KitbenchError(f"dataset folder {root} does not exist")
    info = _info(root)
    tasks = _tasks(root, info)
    episodes = _episodes(root, info, tasks)
    data = _data(root, info, episodes, tasks)
    _videos(root, info, episodes)
    _stats(root)
    _kitbench(root, info, episodes, data)


# -- LeRobot's files ---------------------------------------------------------------------------------------


def _json(path: Path) -> Any:
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise Damage(path, "missing") from None
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise Damage(path, f"unreadable ({one_line(exc, typed=False)})") from None


def _require(path: Path, data: dict, key: str, kind: type, check: Callable[[Any], bool]) -> Any:
    """`data[key]`, of type `kind` (a bool is no int here) and passing `check`."""
    value = data.get(key)
    if not isinstance(value, kind) or (isinstance(value, bool) and kind is not bool) or not check(value):
        raise Damage(path, f"{key} is {value!r}, not a valid value")
    return value


def _info(root: Path) -> dict:
    path = root / INFO_FILE
    info = _json(path)
    if not isinstance(info, dict):
        raise Damage(path, "not a JSON object")
    version = info.get("codebase_version")
    if version != CODEBASE_VERSION:
        raise Damage(path, f"codebase_version is {version!r}; kitbench reads LeRobot {CODEBASE_VERSION} datasets")
    _require(path, info, "fps", int, lambda v: v > 0)
    _require(path, info, "total_episodes", int, lambda v: v >= 0)
    _require(path, info, "total_frames", int, lambda v: v >= 0)
    _require(path, info, "total_tasks", int, lambda v: v >= 0)
    _require(path, info, "data_path", str, lambda v: "{chunk_index" in v and "{file_index" in v)
    for key in ("chunks_size", "data_files_size_in_mb", "video_files_size_in_mb"):  # lerobot's defaults if absent
        if key in info:
            _require(path, info, key, int, lambda v: v > 0)
    for key, kind in (("robot_type", str), ("splits", dict), ("tools", list)):
        if info.get(key) is not None:
            _require(path, info, key, kind, lambda v: True)
    features = _require(path, info, "features", dict, lambda v: len(v) > 0)
    for name, entry in features.items():
        if not (
            isinstance(entry, dict)
            and isinstance(entry.get("dtype"), str)
            and isinstance(entry.get("shape"), list)
            and all(isinstance(n, int) and not isinstance(n, bool) and n > 0 for n in entry["shape"])
        ):
            raise Damage(path, f"feature {name!r} is {entry!r}: not a dtype and a shape")
    if any(f["dtype"] == "video" for f in features.values()):
        _require(path, info, "video_path", str, lambda v: "{video_key" in v and "{file_index" in v)
    return info


def _parquet(path: Path, columns: list[str], whole: bool = False) -> tuple[Any, dict[str, Any]]:
    """A parquet file's schema and `columns` (as numpy arrays of one value a row), or `Damage` naming it; `whole`:
    every column is decoded (lerobot reads all of a metadata file), and returned as Python lists."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    if not path.is_file():
        raise Damage(path, "missing")
    try:
        schema = pq.read_schema(str(path))
        missing = [c for c in columns if c not in schema.names]
        if missing:
            raise Damage(path, f"has no column {missing[0]!r}")
        if whole:
            table = pq.read_table(str(path))
            table.to_pylist()
            return schema, table.to_pydict()
        table = pq.read_table(str(path), columns=columns)
        out = {}
        for c in columns:
            values = table.column(c).to_numpy(zero_copy_only=False)
            out[c] = np.asarray([np.ravel(v)[0] for v in values]) if values.dtype == object else values
        return schema, out
    except (OSError, ValueError, IndexError, pa.ArrowException) as exc:
        raise Damage(path, f"unreadable ({one_line(exc, typed=False)})") from None


def _tasks(root: Path, info: dict) -> dict[int, str]:
    path = root / TASKS_FILE
    schema, table = _parquet(path, ["task_index"], whole=True)
    # the task names are pandas' index, stored as a column named after it
    names = table.get("task") or table.get(schema.pandas_metadata["index_columns"][0] if schema.pandas_metadata else "")
    indices = table["task_index"]
    if names is None or not all(isinstance(i, int) for i in indices) or not all(isinstance(n, str) for n in names):
        raise Damage(path, "does not name each task and its index")
    if sorted(indices) != list(range(len(indices))):
        raise Damage(path, f"task indices {indices} are not 0..{len(indices) - 1}")
    if len(indices) != info["total_tasks"]:
        raise Damage(root / INFO_FILE, f"counts {info['total_tasks']} tasks; {TASKS_FILE} holds {len(indices)}")
    return {i: str(n) for i, n in zip(indices, names, strict=True)}


def _video_keys(info: dict) -> list[str]:
    return [k for k, f in info["features"].items() if f["dtype"] == "video"]


def _episodes(root: Path, info: dict, tasks: dict[int, str]) -> dict[str, np.ndarray]:
    """LeRobot's episode index, in episode order, checked against info.json and itself."""
    folder = root / EPISODES_DIR
    files = sorted(folder.rglob("*.parquet")) if folder.is_dir() else []
    total = info["total_episodes"]
    if not files:
        if total:
            raise Damage(folder, f"holds no episode index, and {INFO_FILE} counts {total} episodes")
        return {}
    columns = ["episode_index", "length", "data/chunk_index", "data/file_index", "dataset_from_index"]
    columns += ["dataset_to_index", "tasks"]
    for key in _video_keys(info):
        columns += [f"videos/{key}/{c}" for c in ("chunk_index", "file_index", "from_timestamp", "to_timestamp")]
    where = {}  # episode index -> the file that lists it
    out: dict[str, list] = {c: [] for c in columns}
    for path in files:
        _, table = _parquet(path, columns, whole=True)  # lerobot reads every column of these
        for c in columns:
            out[c].extend(table[c])
        for i in table["episode_index"]:
            where[i] = path
    for c in columns:
        numbers = int if c != "tasks" and not c.endswith("timestamp") else float if c != "tasks" else list
        if not all(isinstance(v, numbers) or (numbers is float and isinstance(v, int)) for v in out[c]):
            raise Damage(files[0].parent, f"column {c!r} holds a value that is not a {numbers.__name__}")
    order = np.argsort(np.asarray(out["episode_index"]), kind="stable")
    index = {c: [out[c][i] for i in order] for c in columns}
    first = files[0]
    if index["episode_index"] != list(range(len(order))):
        raise Damage(first.parent, f"episode indices are not 0..{len(order) - 1}")
    if len(order) != total:
        raise Damage(root / INFO_FILE, f"counts {total} episodes; {EPISODES_DIR} lists {len(order)}")
    arrays = {c: np.asarray(v) for c, v in index.items() if c != "tasks"}
    lengths, start, end = arrays["length"], arrays["dataset_from_index"], arrays["dataset_to_index"]
    for i in range(len(order)):
        expected = end[i - 1] if i else 0
        if start[i] != expected or end[i] - start[i] != lengths[i] or lengths[i] < 1:
            raise Damage(
                where[i], f"episode {i}: frames {start[i]}..{end[i]} with length {lengths[i]} do not follow on"
            )
        listed = index["tasks"][i]
        if not listed or any(t not in tasks.values() for t in listed):
            raise Damage(where[i], f"episode {i} names tasks {listed!r}, not all in {TASKS_FILE}")
    if int(lengths.sum()) != info["total_frames"]:
        raise Damage(root / INFO_FILE, f"counts {info['total_frames']} frames; the episodes hold {lengths.sum()}")
    return arrays


def _data(root: Path, info: dict, episodes: dict[str, np.ndarray], tasks: dict[int, str]) -> dict[str, np.ndarray]:
    """The index columns (and kitbench's, when there) of every data file, checked against the episode index."""
    if not episodes:
        return {}
    files = sorted(
        {(int(c), int(f)) for c, f in zip(episodes["data/chunk_index"], episodes["data/file_index"], strict=True)}
    )
    expected = {k: f for k, e in info["features"].items() if (f := lerobot_schema.hf_feature(e)) is not None}
    wanted = [*INDEX_COLUMNS, *(c for c in (CARRIER, "next.success") if c in info["features"])]
    columns: dict[str, list[np.ndarray]] = {c: [] for c in wanted}
    for chunk, file in files:
        path = root / info["data_path"].format(chunk_index=chunk, file_index=file)
        schema, table = _parquet(path, wanted)
        try:
            stored = json.loads(schema.metadata[b"huggingface"])["info"]["features"]
            stored = {k: lerobot_schema.stored_form(v) for k, v in stored.items()}
            want = expected
        except (KeyError, TypeError, ValueError):  # written by pandas (LeRobot's aggregation): its arrow types
            stored = {f.name: lerobot_schema.from_arrow(f.type) for f in schema}
            want = {k: lerobot_schema.arrow_view(v) for k, v in expected.items()}
        for name in sorted({*stored, *want}):
            if not lerobot_schema.fits(stored.get(name), want.get(name)):
                raise Damage(path, f"stores feature {name!r} otherwise than {INFO_FILE} says")
        for c in wanted:
            columns[c].append(table[c])
    data = {c: np.concatenate(v) for c, v in columns.items()}
    # each frame where the episode index says: data files in (chunk, file) order hold the episodes in order
    n = int(episodes["length"].sum())
    if len(data["index"]) != n:
        raise Damage(root / "data", f"the data files hold {len(data['index'])} frames; the episodes {n}")
    expected_episode = np.repeat(np.arange(len(episodes["length"])), episodes["length"])
    frame_index = np.arange(n) - np.repeat(episodes["dataset_from_index"], episodes["length"])
    fps = info["fps"]
    checks = {
        "index": np.arange(n),
        "episode_index": expected_episode,
        "frame_index": frame_index,
    }
    for column, want in checks.items():
        bad = np.flatnonzero(data[column] != want)
        if len(bad):
            raise Damage(
                _file_of(root, info, episodes, expected_episode[bad[0]]),
                f"frame {bad[0]} has {column} {data[column][bad[0]]}, not {want[bad[0]]}",
            )
    off = np.flatnonzero(np.abs(data["timestamp"] - frame_index / fps) > 0.5 / fps)
    if len(off):
        raise Damage(
            root / INFO_FILE,
            f"fps {fps} does not match the data's timestamps (frame {off[0]} at {data['timestamp'][off[0]]:.4f} s)",
        )
    unknown = sorted(set(np.unique(data["task_index"]).tolist()) - set(tasks))
    if unknown:
        raise Damage(root / TASKS_FILE, f"has no task {unknown[0]}, which the data uses")
    return data


def _file_of(root: Path, info: dict, episodes: dict[str, np.ndarray], episode: int) -> Path:
    chunk, file = episodes["data/chunk_index"][episode], episodes["data/file_index"][episode]
    return root / info["data_path"].format(chunk_index=int(chunk), file_index=int(file))


def _videos(root: Path, info: dict, episodes: dict[str, np.ndarray]) -> None:
    """Each video file is there and decodes up to its last episode's last frame."""
    if not episodes:
        return
    for key in _video_keys(info):
        chunks, files = episodes[f"videos/{key}/chunk_index"], episodes[f"videos/{key}/file_index"]
        ends = episodes[f"videos/{key}/to_timestamp"]
        last: dict[tuple[int, int], float] = {}
        for chunk, file, end in zip(chunks, files, ends, strict=True):
            last[(int(chunk), int(file))] = max(last.get((int(chunk), int(file)), 0.0), float(end))
        for (chunk, file), end in sorted(last.items()):
            path = root / info["video_path"].format(video_key=key, chunk_index=chunk, file_index=file)
            _check_video(path, end - 1.0 / info["fps"])


def _check_video(path: Path, last_frame: float) -> None:
    import av

    if not path.is_file():
        raise Damage(path, "missing")
    try:
        with av.open(str(path)) as container:
            stream = container.streams.video[0]
            base = stream.time_base
            if base is None:
                raise Damage(path, "its video stream has no time base")
            container.seek(max(int((last_frame - 1.0) / base), 0), stream=stream, backward=True)
            for frame in container.decode(stream):
                if frame.pts is not None and float(frame.pts * base) >= last_frame - 1e-3:
                    return
    except (av.FFmpegError, OSError, IndexError, ValueError) as exc:
        raise Damage(path, f"unreadable ({one_line(exc, typed=False)})") from None
    raise Damage(path, f"ends before {last_frame:.3f} s, the last frame its episodes need")


def _stats(root: Path) -> None:
    path = root / STATS_FILE
    if path.exists():
        stats = _json(path)
        if not isinstance(stats, dict) or not all(isinstance(v, dict) for v in stats.values()):
            raise Damage(path, "not a JSON object of per-feature statistics")


# -- kitbench's files --------------------------------------------------------------------------------------


def _kitbench(root: Path, info: dict, episodes: dict[str, np.ndarray], data: dict[str, np.ndarray]) -> None:
    """kitbench's settings and episode file agree with what LeRobot's files and the data say (when there: a
    recording after LeRobot's tools has neither, and is read from its features and columns)."""
    settings_path = root / RECORDING_FILE
    remedy = "delete it, and kitbench reads the same facts back from the dataset"
    recording = None
    if settings_path.exists():
        raw = _json(settings_path)
        if not isinstance(raw, dict):
            raise Damage(settings_path, "not a JSON object", remedy)
        try:
            recording = RecordingInfo.from_json(raw)
            recording.validate()
        except (KitbenchError, TypeError, ValueError) as exc:
            raise Damage(settings_path, one_line(exc, typed=False), remedy) from None
        carried = carried_settings(info)
        if carried is not None:
            mine = recording.carried()
            differing = sorted(k for k in {*mine, *carried} if k != "format" and mine.get(k) != carried.get(k))
            if differing:
                raise Damage(
                    settings_path,
                    f"{differing[0]} is {mine.get(differing[0])!r}, but {INFO_FILE} carries "
                    f"{carried.get(differing[0])!r}",
                    remedy,
                )
        if recording.features_sha256 is not None and features_digest(info["features"]) != recording.features_sha256:
            raise Damage(
                root / INFO_FILE,
                f"its features were changed after kitbench wrote them (their digest in {RECORDING_FILE} differs)",
            )
        if recording.fps != info["fps"] and (
            recording.fps is not None or recording.format >= 2
        ):  # numbered files keep it
            raise Damage(settings_path, f"fps is {recording.fps}, but {INFO_FILE} says {info['fps']}", remedy)
    seeds = _episode_seeds(data, episodes)
    if recording is not None and seeds:
        asked = recording.implied_seeds(len(seeds))
        if asked != seeds and not recording.only_success:
            raise Damage(settings_path, f"says seeds {_span(asked)}; the data holds {_span(seeds)}", remedy)
        if recording.seed != min(seeds) and recording.seeds is None:
            raise Damage(settings_path, f"says first seed {recording.seed}; the data's is {min(seeds)}", remedy)
    _episode_file(root, recording, episodes, data, seeds, remedy)


def _span(seeds: list[int]) -> str:
    return f"{seeds[0]}..{seeds[-1]} ({len(seeds)})" if seeds else "none"


def _episode_seeds(data: dict[str, np.ndarray], episodes: dict[str, np.ndarray]) -> list[int]:
    if CARRIER not in data or not episodes:
        return []
    return [int(s) for s in data[CARRIER][episodes["dataset_from_index"]]]


def _episode_file(
    root: Path,
    recording: RecordingInfo | None,
    episodes: dict[str, np.ndarray],
    data: dict[str, np.ndarray],
    seeds: list[int],
    remedy: str,
) -> None:
    path = root / EPISODES_FILE
    if not path.exists():
        return
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise Damage(path, f"unreadable ({one_line(exc, typed=False)})", remedy) from None
    digest = None if recording is None else recording.episodes_sha256
    if digest is not None and episodes_digest(text.encode()) != digest:
        raise Damage(path, f"was changed after kitbench wrote it (its digest in {RECORDING_FILE} differs)", remedy)
    lines: list[EpisodeInfo] = []
    for number, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        try:
            entry = json.loads(line)
            if not isinstance(entry, dict):
                raise ValueError("not a JSON object")
            lines.append(EpisodeInfo.from_json(entry))
            lines[-1].validate()
        except (TypeError, ValueError, KitbenchError) as exc:
            raise Damage(path, f"line {number}: {one_line(exc, typed=False)}", remedy) from None
    if len(lines) != len(episodes.get("length", [])) or [e.episode_index for e in lines] != list(range(len(lines))):
        return  # stale after an in-place LeRobot tool: kitbench reads each episode's facts from the data instead
    success = data.get("next.success")
    known: list[int | None] = list(seeds) or [None] * len(lines)
    for episode, seed in zip(lines, known, strict=True):
        i = episode.episode_index
        length = int(episodes["length"][i])
        if seed is not None and episode.seed != seed:
            raise Damage(path, f"episode {i} has seed {episode.seed}; its data, {seed}", remedy)
        if episode.length != length:
            raise Damage(path, f"episode {i} has length {episode.length}; its data, {length}", remedy)
        if success is not None:
            start = int(episodes["dataset_from_index"][i])
            hits = np.flatnonzero(success[start : start + length])
            first = int(hits[0]) if len(hits) else None
            if episode.first_success != first or episode.success != (first is not None):
                raise Damage(
                    path,
                    f"episode {i} says success {episode.success} at {episode.first_success}; its data, "
                    f"{first is not None} at {first}",
                    remedy,
                )
