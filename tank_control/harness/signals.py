"""SIGINT, SIGTERM and SIGHUP during a run: the first is noted and raised as
``RunInterrupted`` at the run's next ``check()``, so the harness stops its nodes and closes
its files (docs/harness.md, "Interrupted and failed runs"); a second one raises at once.
Installed only from the main thread."""
from __future__ import annotations

import signal
import threading
from pathlib import Path
from types import FrameType
from typing import Any

SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


class RunInterrupted(BaseException):
    """The run was stopped by a signal (a ``BaseException`` like ``KeyboardInterrupt``)."""

    partial_results: Path | None = None     # the run's directory, once written

    def __init__(self, signum: int) -> None:
        self.signum = signum
        super().__init__(f'interrupted by {signal.Signals(signum).name}')

    @property
    def exit_code(self) -> int:
        """The shell's code for a process ended by this signal (128 + number)."""
        return 128 + self.signum


class StopSignals:
    """Note SIGINT/SIGTERM/SIGHUP while active; ``check()`` raises the first as
    ``RunInterrupted``."""

    def __init__(self) -> None:
        self.received: int | None = None
        self._previous: dict[int, Any] = {}

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        if self.received is None:
            self.received = signum
            return
        raise RunInterrupted(signum)          # the second signal: no more patience

    def check(self) -> None:
        if self.received is not None:
            raise RunInterrupted(self.received)

    def __enter__(self) -> StopSignals:
        if threading.current_thread() is threading.main_thread():
            for sig in SIGNALS:
                self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, exc_type: type | None, *exc: object) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous.clear()
        if exc_type is None:
            self.check()          # a signal after the last check: the run is done, stop now
