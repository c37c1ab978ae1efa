"""ROS_DOMAIN_IDs held by file locks (``flock``; a lock dies with its process), two kinds:

* a *claim* (``claim``, ``claimed``): ``<tmp>/tank_control_domains/<id>.lock``, a free domain
  taken for a while by one holder (a test session, a lockstep sweep run), so concurrent graphs
  on one host never see each other. Ids 1…100 are valid for LOCALHOST discovery on Linux.
* a *run lock* (``lock_run``): ``<tmp>/tank_control_runs/domain-<id>.lock``, held by every ROS
  run of the harness for its whole length: one run at a time on a domain on this host, whoever
  claimed it (the runs of a test session all happen inside its claim).
"""
from __future__ import annotations

import errno
import fcntl
import os
import random
import tempfile
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import IO

LOCK_DIR = Path(tempfile.gettempdir()) / 'tank_control_domains'
RUN_LOCK_DIR = Path(tempfile.gettempdir()) / 'tank_control_runs'
DOMAIN_IDS = tuple(range(1, 101))


def claim() -> tuple[int, IO[str]]:
    """Lock a free domain id; returns it and the open lock file (close it to release)."""
    LOCK_DIR.mkdir(exist_ok=True)
    candidates = list(DOMAIN_IDS)
    random.SystemRandom().shuffle(candidates)
    for domain_id in candidates:
        handle = open(LOCK_DIR / f'{domain_id}.lock', 'w')
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            handle.close()
            continue
        return domain_id, handle
    raise RuntimeError(f'no free ROS_DOMAIN_ID in {DOMAIN_IDS[0]}..{DOMAIN_IDS[-1]} '
                       f'(all locked in {LOCK_DIR})')


@contextmanager
def claimed() -> Iterator[int]:
    """A free domain id, held for the ``with`` block."""
    domain_id, handle = claim()
    try:
        yield domain_id
    finally:
        handle.close()


def domain_of(env: Mapping[str, str]) -> str:
    """The ROS domain a process with environment ``env`` joins (ROS 2's default is 0)."""
    return env.get('ROS_DOMAIN_ID', '').strip() or '0'


@dataclass
class RunLock:
    """The held run lock of one domain on this host (``release()`` or the process's end
    frees it)."""

    domain: str
    path: Path
    handle: IO[str] | None

    def release(self) -> None:
        if self.handle is not None:
            self.handle.close()                # closing the file drops the flock
            self.handle = None


def lock_run(domain: str, owner: str) -> tuple[RunLock, str | None]:
    """Try to take the run lock of ``domain``: (the lock, None), or (an unheld lock, the
    reason naming the run that holds it). ``owner`` (e.g. the output directory) is written
    into the lock file for that message. A lock file that cannot be created is no reason to
    refuse."""
    path = RUN_LOCK_DIR / f'domain-{domain}.lock'
    try:
        RUN_LOCK_DIR.mkdir(exist_ok=True)
        try:
            RUN_LOCK_DIR.chmod(0o1777)         # shared by every user, like /tmp
        except OSError:
            pass
        try:
            handle = open(path, 'a+')
        except PermissionError:                # another user's file: flock works read-only
            handle = open(path)
    except OSError:
        return RunLock(domain, path, None), None
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as exc:
        if exc.errno not in (errno.EAGAIN, errno.EACCES, errno.EWOULDBLOCK):
            handle.close()
            return RunLock(domain, path, None), None
        handle.seek(0)
        holder = handle.read().strip() or 'unknown'
        handle.close()
        return RunLock(domain, path, None), (
            f'ROS_DOMAIN_ID {domain} is in use by another tank-control run on this host '
            f'({holder}); wait for it to end or set a different ROS_DOMAIN_ID')
    if handle.writable():
        handle.seek(0)
        handle.truncate()
        handle.write(f'pid {os.getpid()}, output {owner}\n')
        handle.flush()
    return RunLock(domain, path, handle), None
