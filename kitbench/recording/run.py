"""`RecordingRun`: what a recording on one writer (`one_writer.Recording`) and a sharded one
(`shards.ShardedRecording`) share around their own loop: the summary and the attempt limit, the progress bar,
Ctrl-C / SIGTERM / SIGHUP (finish storing what is at hand, stop, say how to resume) and a lost Ray cluster (one
line saying that everything finished before is kept)."""

from __future__ import annotations

import signal
from abc import ABC, abstractmethod
from typing import Any, ClassVar

from kitbench.engine import RolloutEngine
from kitbench.engine.executor import ClusterLost
from kitbench.errors import KitbenchError
from kitbench.recording.config import RecordConfig
from kitbench.recording.stops import Stopped, StopSignals
from kitbench.recording.summary import Summary, attempt_limit


class RecordingRun(ABC):
    """One recording's run: `run` calls the hooks in this order, `_start`, then `_record` with the signals turned
    into `Stopped`, then `_recorded`; a stop or a lost cluster ends it as the class says."""

    # what the journal keeps whole when the run ends early, as the lost-cluster message names it
    kept: ClassVar[str] = "episode"

    def __init__(self, config: RecordConfig, summary: Summary, progress: bool):
        self.config, self.summary, self.progress = config, summary, progress
        self.limit = attempt_limit(config)
        self.bar: Any = None

    # -- hooks ----------------------------------------------------------------------------------------------------
    def _start(self, engine: RolloutEngine | None) -> None:  # noqa: B027  (optional: most runs start nothing)
        """Before the signals are caught (nothing by default)."""

    @abstractmethod
    def _record(self, engine: RolloutEngine | None, stops: StopSignals) -> None:
        """Record and commit, storing inside `stops.storing()` (a signal waits until what is stored is whole)."""

    def _recorded(self) -> None:  # noqa: B027  (optional)
        """After `_record` returned, the signals restored (nothing by default)."""

    def _stopped(self) -> None:  # noqa: B027  (optional)
        """On a stop, before the summary says so: keep what is stored (nothing by default: it is journaled)."""

    def _abandon(self) -> None:  # noqa: B027  (optional)
        """On any other error: drop what is half-written, keep the journal (nothing by default)."""

    # -- the run --------------------------------------------------------------------------------------------------
    def run(self, engine: RolloutEngine | None, signals: bool = True) -> Summary:
        """`signals`: Ctrl-C, SIGTERM and SIGHUP stop the run cleanly (off in a shard's worker, whose signals are
        its pool's)."""
        try:
            self._start(engine)
            with StopSignals(enabled=signals) as stops:
                self._record(engine, stops)
            self._recorded()
        except KeyboardInterrupt as exc:
            self._stopped()
            self.summary.interrupted = True
            self.summary.signal = exc.signum if isinstance(exc, Stopped) else signal.SIGINT
        except ClusterLost as exc:
            self._abandon()
            raise KitbenchError(f"{exc}; every {self.kept} finished before is kept: continue with --resume") from None
        except BaseException:
            self._abandon()
            raise
        finally:
            if self.bar is not None:
                self.bar.close()
        return self.summary

    def _open_bar(self, total: int, label: str) -> None:
        """A progress bar of `total` episodes, when the run shows progress."""
        if self.progress:
            from kitbench.progress import progress as progress_bar

            self.bar = progress_bar(total, label)
