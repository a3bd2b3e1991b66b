"""Filming an evaluation: which scored episodes to film, and replaying them on the engine in an env that renders,
each video written whole into the report folder and checked against the episode it films."""

from __future__ import annotations

from pathlib import Path

from kitbench import faults
from kitbench.engine import RolloutEngine
from kitbench.errors import one_line
from kitbench.evaluation.episode import EpisodeResult
from kitbench.evaluation.output import VIDEOS_DIR
from kitbench.evaluation.work import Film


def pick_video_seeds(results: list[EpisodeResult], count: int) -> list[EpisodeResult]:
    """`count` episodes to film, failures and successes both: half of each (the first ones by seed order),
    the other kind filling in when one runs short."""
    if count <= 0:
        return []
    failures = [r for r in results if not r.success]
    successes = [r for r in results if r.success]
    n_fail = min(len(failures), max(count - len(successes), (count + 1) // 2))
    chosen = {id(r) for r in failures[:n_fail] + successes[: count - n_fail]}
    return [r for r in results if id(r) in chosen]


def film(
    engine: RolloutEngine, chosen: list[EpisodeResult], out: Path, fps: int, videos: list[dict], progress: bool
) -> None:
    """Replay and film `chosen`, appending each video to `videos` as soon as it is written (so the ones made
    before a failure stay listed)."""
    bar = None
    if progress:  # filming renders every step: seconds a video on a CPU, so it gets a bar of its own
        from kitbench.progress import progress as progress_bar

        bar = progress_bar(len(chosen), "videos")
    try:
        _film_each(engine, chosen, out, fps, videos, bar)
    finally:
        if bar is not None:
            bar.close()


def _film_each(engine: RolloutEngine, chosen: list[EpisodeResult], out: Path, fps: int, videos: list[dict], bar):
    for scored, (replayed, mp4) in zip(chosen, engine.map(Film(r.seed, fps) for r in chosen), strict=True):
        path = out / VIDEOS_DIR / f"seed{scored.seed}_{'success' if scored.success else 'failure'}.mp4"
        path.parent.mkdir(parents=True, exist_ok=True)
        partial = path.with_name(f".{path.name}.partial")
        partial.write_bytes(mp4)
        partial.replace(path)  # a video under its name is whole
        faults.point("eval.filmed")
        same = (replayed.success, replayed.length, replayed.episode_return) == (
            scored.success,
            scored.length,
            scored.episode_return,
        )
        videos.append(
            {
                "seed": scored.seed,
                "success": scored.success,
                "failure": scored.failure,
                "path": str(path.relative_to(out)),
                "matches_scored_episode": same,
            }
        )
        if bar is not None:
            bar.update(1)


def video_error(exc: Exception) -> str:
    """One line on why the videos could not be made: `kitbench doctor`'s line when this machine has no render
    device, else the exception's type and first line."""
    from kitbench.doctor import vulkan_error

    no_device = vulkan_error()
    if no_device is not None:
        return no_device
    return one_line(exc)
