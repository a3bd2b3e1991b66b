"""Episode videos as H.264 MP4 through PyAV (a LeRobot dependency), playable in any browser."""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import numpy as np


def write_mp4(path: Path, frames: list[np.ndarray], fps: int, crf: int = 23) -> Path:
    """Encode HxWx3 uint8 frames; the file appears only once complete."""
    import av
    import av.logging

    av.logging.set_level(av.logging.ERROR)  # the encoder's statistics are noise on a terminal
    if not frames:
        raise ValueError(f"no frames to write to {path}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(f".{path.name}.partial")
    height, width = frames[0].shape[:2]
    try:
        with av.open(str(partial), mode="w", format="mp4") as container:
            stream = container.add_stream("libx264", rate=Fraction(fps))
            stream.width, stream.height = width - width % 2, height - height % 2
            stream.pix_fmt = "yuv420p"
            stream.options = {"crf": str(crf), "preset": "veryfast"}
            for rgb in frames:
                rgb = np.ascontiguousarray(rgb[: stream.height, : stream.width, :3])
                container.mux(stream.encode(av.VideoFrame.from_ndarray(rgb, format="rgb24")))
            container.mux(stream.encode())
    except BaseException:
        partial.unlink(missing_ok=True)  # a failed encode leaves no half-written file in the report folder
        raise
    partial.replace(path)
    return path
