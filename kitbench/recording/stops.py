"""Ctrl-C, SIGTERM and SIGHUP while recording: finish storing the episode at hand, then stop (the recorder
commits what it has and exits with 128 + the signal)."""

from __future__ import annotations

import signal
import threading
from contextlib import contextmanager


class Stopped(KeyboardInterrupt):
    """Ctrl-C, SIGTERM or SIGHUP: commit what is stored, say so, exit non-zero."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


class StopSignals:
    """Turn SIGINT, SIGTERM and SIGHUP into `Stopped` while recording (main thread only; restored afterwards).

    Inside `storing()` a signal is held until the episode being stored is in the journal and the session: raised
    in the middle, it would lose an episode that had finished."""

    def __init__(self, enabled: bool = True):
        # disabled in a recording that runs inside a worker (a shard): the worker's signals are its pool's or Ray's
        # to handle (a pool ends its workers with SIGTERM, which must end them)
        self.enabled = enabled
        self._old: dict = {}
        self._storing = False
        self._held: int | None = None

    def _handle(self, signum, frame):
        if self._storing:
            self._held = signum
        else:
            raise Stopped(signum)

    def __enter__(self):
        if self.enabled and threading.current_thread() is threading.main_thread():
            for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
                self._old[signum] = signal.signal(signum, self._handle)
        return self

    def __exit__(self, *exc):
        for signum, handler in self._old.items():
            signal.signal(signum, handler)

    @contextmanager
    def storing(self):
        self._storing = True
        try:
            yield
        finally:
            self._storing = False
        if self._held is not None:
            raise Stopped(self._held)
