"""`kitbench record`: run a policy (the expert by default) over consecutive seeds and write a LeRobot dataset
with one MCAP log per episode in `<out>/mcap/`.

`record` checks everything (`config.validate`), then records on one writer (`one_writer.record_episodes`) or in
shards (`shards.record_sharded`, each shard a `record_episodes` of its own in a worker).
"""

from __future__ import annotations

from pathlib import Path

from kitbench.recording.config import RecordConfig, load_recipe, make_recording_env, validate
from kitbench.recording.one_writer import record_episodes
from kitbench.recording.session import MCAP_DIR
from kitbench.recording.summary import Summary

__all__ = ["MCAP_DIR", "RecordConfig", "Summary", "load_recipe", "make_recording_env", "record", "validate"]


def record(config: RecordConfig, progress: bool = True, signals: bool = True) -> Summary:
    """Record `config.demo.episodes` episodes (continuing a recording with `resume`); see the module docstring.
    `signals`: Ctrl-C, SIGTERM and SIGHUP stop the recording cleanly."""
    validate(config)
    if config.executor.shard_episodes:
        from kitbench.recording.shards import record_sharded

        return record_sharded(config, progress)
    return record_episodes(config, progress, signals)


def recipe_or_flags(recipe: Path | None, flags: dict) -> RecordConfig:
    """What the command line asks: a recipe with the flags on top, or the flags alone."""
    if recipe is not None:
        return load_recipe(recipe, **flags)
    return RecordConfig.of(**{k: v for k, v in flags.items() if v is not None})
