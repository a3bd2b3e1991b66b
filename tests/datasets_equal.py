"""Whether two recordings hold the same episodes: what a resumed, sharded or converted recording is compared by."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from kitbench.integrity import check_dataset
from kitbench.recording.layout import JOURNAL_SUFFIX, RETIRED_SUFFIX, SESSION_SUFFIX, beside


def frames(root: Path) -> pd.DataFrame:
    return pd.concat([pd.read_parquet(p) for p in sorted((root / "data").rglob("*.parquet"))], ignore_index=True)


def same_content(a: Path, b: Path) -> None:
    """The same frames (every data column), episode metadata, settings, totals and MCAP logs byte for byte, however
    the parquet and video files are split (each commit of a resumed recording starts new ones); both pass
    `check_dataset` and stock lerobot loads both."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    fa, fb = frames(a), frames(b)
    assert list(fa.columns) == list(fb.columns) and len(fa) == len(fb), (list(fa.columns), len(fa), len(fb))
    for column in fa.columns:
        np.testing.assert_array_equal(np.stack(fa[column].to_numpy()), np.stack(fb[column].to_numpy()), column)
    for name in ("meta/kitbench_episodes.jsonl", "meta/kitbench_recording.json"):
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
    info_a, info_b = (json.loads((r / "meta/info.json").read_text()) for r in (a, b))
    for key in ("total_episodes", "total_frames", "total_tasks", "fps", "features"):
        assert info_a[key] == info_b[key], key
    logs = sorted(p.name for p in (a / "mcap").iterdir()) if (a / "mcap").is_dir() else []
    assert logs == (sorted(p.name for p in (b / "mcap").iterdir()) if (b / "mcap").is_dir() else [])
    assert all((a / "mcap" / n).read_bytes() == (b / "mcap" / n).read_bytes() for n in logs)
    for root in (a, b):
        key = (str(root.resolve()), _files(root))
        if key in _WHOLE:  # a reference compared again, unchanged since it passed: its checks would repeat
            continue
        check_dataset(root)
        assert LeRobotDataset("kitbench/test", root=root).num_episodes == info_a["total_episodes"]
        _WHOLE.add(key)


_WHOLE: set[tuple] = set()  # recordings that passed check_dataset and loaded, as (path, their files) when they did


def _files(root: Path) -> tuple:
    """Every file under root with its size and modification time: any write changes it."""
    return tuple(
        sorted(
            (str(p.relative_to(root)), p.stat().st_size, p.stat().st_mtime_ns) for p in root.rglob("*") if p.is_file()
        )
    )


def no_leftovers(out: Path) -> None:
    """A finished recording leaves its dataset folder only: no session, folder set aside or journal."""
    for suffix in (SESSION_SUFFIX, RETIRED_SUFFIX, JOURNAL_SUFFIX, ".merged", ".merging"):
        assert not beside(out, suffix).exists(), beside(out, suffix)


def older_recording(root: Path, **settings) -> None:
    """Make the recording at `root` read as one made with other `settings` (an older kitbench, say): its settings
    file, the settings its features carry and the digests written with them, all as that kitbench wrote them, so
    that `check_dataset` sees a whole recording and not a hand edit."""
    import dataclasses

    from kitbench.metadata import INFO_FILE, RecordingInfo

    info = dataclasses.replace(RecordingInfo.read(root), **settings)
    lerobot = json.loads((root / INFO_FILE).read_text())
    lerobot["features"] = info.carry(lerobot["features"])
    (root / INFO_FILE).write_text(json.dumps(lerobot, indent=4))
    info.write(root)
