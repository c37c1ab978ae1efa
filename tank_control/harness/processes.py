"""Start node processes in their own process groups and stop them without leftovers.

Used by the scenario harness and by the tests: every process is a session
leader (``start_new_session``), so stopping signals its whole group, and a stop
escalates SIGINT → SIGTERM → SIGKILL.
"""
from __future__ import annotations

import os
import signal
import subprocess
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO


@dataclass
class ManagedProcess:
    """One started process with its log file (stdout and stderr together)."""

    name: str
    popen: subprocess.Popen
    log_path: Path
    _log: IO[bytes] = field(repr=False)

    @property
    def returncode(self) -> int | None:
        return self.popen.poll()

    def tail(self, lines: int = 20) -> str:
        """The last ``lines`` lines of the process's output."""
        self._log.flush()
        text = self.log_path.read_text(errors='replace')
        return '\n'.join(text.splitlines()[-lines:])


def _signal_group(popen: subprocess.Popen, sig: signal.Signals) -> None:
    try:
        os.killpg(popen.pid, sig)
    except ProcessLookupError:
        pass


def stop_process(proc: ManagedProcess, grace: float = 5.0) -> int:
    """SIGINT the group, then SIGTERM, then SIGKILL; return the exit code."""
    for sig, wait in ((signal.SIGINT, grace), (signal.SIGTERM, grace), (signal.SIGKILL, grace)):
        if proc.popen.poll() is not None:
            break
        _signal_group(proc.popen, sig)
        try:
            proc.popen.wait(timeout=wait)
        except subprocess.TimeoutExpired:
            continue
    # Children that outlived their leader still belong to the group.
    _signal_group(proc.popen, signal.SIGKILL)
    proc._log.close()
    return proc.popen.returncode


class ProcessGroup:
    """A set of processes stopped together (context manager)."""

    def __init__(self, log_dir: Path) -> None:
        self.log_dir = Path(log_dir)
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.processes: dict[str, ManagedProcess] = {}

    def start(self, name: str, argv: Sequence[str],
              env: Mapping[str, str] | None = None,
              cwd: str | os.PathLike | None = None) -> ManagedProcess:
        """Start ``argv`` as a new session, output to ``<log_dir>/<name>.log``."""
        if name in self.processes:
            raise ValueError(f'process name {name!r} already used')
        log_path = self.log_dir / f'{name}.log'
        log = open(log_path, 'wb')
        popen = subprocess.Popen(list(argv), stdin=subprocess.DEVNULL, stdout=log,
                                 stderr=subprocess.STDOUT, env=dict(env) if env else None,
                                 cwd=cwd, start_new_session=True)
        proc = ManagedProcess(name, popen, log_path, log)
        self.processes[name] = proc
        return proc

    def stop(self, name: str, grace: float = 5.0) -> int:
        return stop_process(self.processes[name], grace)

    def stop_all(self, grace: float = 5.0) -> dict[str, int]:
        """Stop in reverse start order; return every exit code by name."""
        return {name: stop_process(proc, grace)
                for name, proc in reversed(list(self.processes.items()))}

    def __enter__(self) -> ProcessGroup:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop_all()
