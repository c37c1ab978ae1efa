"""Start node processes in their own process groups and stop them without leftovers.

Used by the scenario harness and by the tests: every process is a session
leader (``start_new_session``), so stopping signals its whole group, and a stop
escalates SIGINT → SIGTERM → SIGKILL.

A started process dies with the process that started it even when that one
cannot stop it (SIGKILL, a crash): Linux's parent-death signal
(``prctl(PR_SET_PDEATHSIG, SIGKILL)``, kept across ``exec``) is set in the child
before it runs its program. The kernel sends it when the *thread* that started
the child ends, so start processes from a thread that outlives them (the
harness and the tests start them from the main thread).

A process that has exited is not reaped until it is stopped: ``returncode``
looks without reaping (``waitid`` with ``WNOWAIT``). While the exited leader
is a zombie its pid — the group id — cannot be reused, so the final SIGKILL
of the group can never reach an unrelated process that got the pid meanwhile
(pids wrap around quickly on a busy host: ``pid_max`` is 32768 by default and
every thread takes one).
"""
from __future__ import annotations

import ctypes
import os
import signal
import subprocess
import sys
from collections.abc import Callable, Mapping, Sequence
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
    argv: tuple[str, ...] = ()
    env: dict[str, str] | None = field(default=None, repr=False)
    cwd: str | os.PathLike | None = None
    starts: int = 1                    # 1 + the restarts (``ProcessGroup.restart``)

    @property
    def returncode(self) -> int | None:
        """The exit code (negative: killed by that signal), None while running; the
        process is not reaped (see the module doc)."""
        return exit_code(self.popen)

    def cpu_seconds(self) -> float | None:
        """CPU time (user + system) the process has used so far [s]; None where
        ``/proc`` cannot tell (not Linux, or the process is gone)."""
        return process_cpu_seconds(self.popen.pid)

    def tail(self, lines: int = 20) -> str:
        """The last ``lines`` lines of the process's output (also once it was stopped)."""
        if not self._log.closed:
            self._log.flush()
        text = self.log_path.read_text(errors='replace')
        return '\n'.join(text.splitlines()[-lines:])


def process_cpu_seconds(pid: int) -> float | None:
    """utime + stime of ``pid`` from ``/proc/<pid>/stat`` [s] (None if unreadable)."""
    try:
        with open(f'/proc/{pid}/stat', 'rb') as stat:
            fields = stat.read().rsplit(b')', 1)[1].split()
    except OSError:
        return None
    # after the command's closing parenthesis: state is field 3, utime 14, stime 15
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def exit_code(popen: subprocess.Popen) -> int | None:
    """Like ``popen.poll()`` but leaves an exited child a zombie (its pid stays reserved)."""
    if popen.returncode is not None:
        return popen.returncode
    try:
        info = os.waitid(os.P_PID, popen.pid, os.WEXITED | os.WNOHANG | os.WNOWAIT)
    except ChildProcessError:          # reaped elsewhere (a direct popen.wait())
        return popen.poll()
    if info is None:
        return None
    return info.si_status if info.si_code == os.CLD_EXITED else -info.si_status


_PR_SET_PDEATHSIG = 1


def _die_with_parent() -> Callable[[], None] | None:
    """A ``preexec_fn``: in the child, before ``exec``, SIGKILL on the parent's end; if the
    parent already ended between ``fork`` and here, end now. None off Linux."""
    if not sys.platform.startswith('linux'):
        return None
    prctl = ctypes.CDLL(None, use_errno=True).prctl      # looked up here, not in the child
    parent = os.getpid()

    def hook() -> None:
        if prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) != 0 or os.getppid() != parent:
            os._exit(127)
    return hook


def _signal_group(popen: subprocess.Popen, sig: signal.Signals) -> None:
    try:
        os.killpg(popen.pid, sig)
    except ProcessLookupError:
        pass


def stop_process(proc: ManagedProcess, grace: float = 5.0, interrupted: bool = False) -> int:
    """SIGINT the group, then SIGTERM, then SIGKILL; return the exit code. ``interrupted``:
    the SIGINT was sent already (``ProcessGroup.stop_all``): wait for it, then go on."""
    popen = proc.popen
    if popen.returncode is None and exit_code(popen) is not None:
        # Exited on its own and not reaped yet: its children (if any) go with the group
        # while the zombie leader still holds the group id.
        _signal_group(popen, signal.SIGKILL)
    for sig, wait in ((signal.SIGINT, grace), (signal.SIGTERM, grace), (signal.SIGKILL, grace)):
        if exit_code(popen) is not None:
            break
        if not (interrupted and sig == signal.SIGINT):
            _signal_group(popen, sig)
        try:
            popen.wait(timeout=wait)
        except subprocess.TimeoutExpired:
            continue
        # Children that outlived their leader still belong to the group (the group id
        # was the leader's pid a moment ago; it cannot have been handed out again yet).
        _signal_group(popen, signal.SIGKILL)
    popen.wait()                       # reap (the group is gone)
    proc._log.close()
    return popen.returncode


def _popen(argv: Sequence[str], log: IO[bytes], env: Mapping[str, str] | None,
           cwd: str | os.PathLike | None) -> subprocess.Popen:
    return subprocess.Popen(list(argv), stdin=subprocess.DEVNULL, stdout=log,
                            stderr=subprocess.STDOUT, env=dict(env) if env else None, cwd=cwd,
                            start_new_session=True, preexec_fn=_die_with_parent())


class ProcessGroup:
    """A set of processes stopped together (context manager)."""

    def __init__(self, log_dir: Path) -> None:
        self.log_dir = Path(log_dir)
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.processes: dict[str, ManagedProcess] = {}

    def start(self, name: str, argv: Sequence[str],
              env: Mapping[str, str] | None = None,
              cwd: str | os.PathLike | None = None) -> ManagedProcess:
        """Start ``argv`` as a new session, output to ``<log_dir>/<name>.log``; it is killed
        when this process ends (see the module doc)."""
        if name in self.processes:
            raise ValueError(f'process name {name!r} already used')
        log_path = self.log_dir / f'{name}.log'
        log = open(log_path, 'wb')
        proc = ManagedProcess(name, _popen(argv, log, env, cwd), log_path, log, tuple(argv),
                              dict(env) if env else None, cwd)
        self.processes[name] = proc
        return proc

    def restart(self, name: str, note: str = '') -> ManagedProcess:
        """Start the exited process ``name`` again with the same command, environment and
        directory (its group stopped and reaped first, so nothing of the old one is left);
        its output goes on in the same log after a line ``note``."""
        old = self.processes[name]
        if exit_code(old.popen) is None:
            raise ValueError(f'process {name!r} is still running')
        stop_process(old)
        log = open(old.log_path, 'ab')
        if note:
            log.write(f'\n--- {note} ---\n'.encode())
            log.flush()
        proc = ManagedProcess(name, _popen(old.argv, log, old.env, old.cwd), old.log_path, log,
                              old.argv, old.env, old.cwd, old.starts + 1)
        self.processes[name] = proc
        return proc

    def stop(self, name: str, grace: float = 5.0) -> int:
        return stop_process(self.processes[name], grace)

    def stop_all(self, grace: float = 5.0) -> dict[str, int]:
        """Stop every process (SIGINT to all in reverse start order at once, so that they stop
        together, not one after the other: about 0.2 s each for a node); return every exit
        code by name."""
        procs = list(reversed(list(self.processes.items())))
        interrupted = set()
        for name, proc in procs:
            if exit_code(proc.popen) is None:
                _signal_group(proc.popen, signal.SIGINT)
                interrupted.add(name)
        return {name: stop_process(proc, grace, name in interrupted) for name, proc in procs}

    def __enter__(self) -> ProcessGroup:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop_all()
