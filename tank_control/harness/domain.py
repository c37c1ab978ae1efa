"""One run per ROS_DOMAIN_ID, checked before a run writes, subscribes or starts anything: a
per-host lock on the domain (``lock_domain``), then a look at the graph for another run's
node names or publishers of the run's topics (``foreign_graph``). Steps and reasons:
docs/harness.md ("How a ROS run proceeds", step 0). Times in wall seconds."""
from __future__ import annotations

import errno
import fcntl
import os
import tempfile
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

#: Node names a run uses (the recorder's is ``recorder.RECORDER_NAME``).
RUN_NODE_NAMES = ('plant', 'controller', 'reference')


def lock_dir() -> Path:
    return Path(tempfile.gettempdir()) / 'tank_control_runs'


@dataclass
class DomainLock:
    """The held lock of one domain on this host (``release()`` or the process's end frees it)."""

    domain: str
    path: Path
    handle: IO[str] | None

    def release(self) -> None:
        if self.handle is not None:
            self.handle.close()                # closing the file drops the flock
            self.handle = None


def lock_domain(domain: str, owner: str) -> tuple[DomainLock, str | None]:
    """Try to take the lock of ``domain``: (the lock, None), or (an unheld lock, the reason
    naming the run that holds it). ``owner`` (e.g. the output directory) is written into the
    lock file for that message. A lock file that cannot be created is no reason to refuse."""
    directory = lock_dir()
    path = directory / f'domain-{domain}.lock'
    try:
        directory.mkdir(exist_ok=True)
        try:
            directory.chmod(0o1777)            # shared by every user, like /tmp
        except OSError:
            pass
        try:
            handle = open(path, 'a+')
        except PermissionError:                # another user's file: flock works read-only
            handle = open(path)
    except OSError:
        return DomainLock(domain, path, None), None
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as exc:
        if exc.errno not in (errno.EAGAIN, errno.EACCES, errno.EWOULDBLOCK):
            handle.close()
            return DomainLock(domain, path, None), None
        handle.seek(0)
        holder = handle.read().strip() or 'unknown'
        handle.close()
        return DomainLock(domain, path, None), (
            f'ROS_DOMAIN_ID {domain} is in use by another tank-control run on this host '
            f'({holder}); wait for it to end or set a different ROS_DOMAIN_ID')
    if handle.writable():
        handle.seek(0)
        handle.truncate()
        handle.write(f'pid {os.getpid()}, output {owner}\n')
        handle.flush()
    return DomainLock(domain, path, handle), None


def domain_of(env: Mapping[str, str]) -> str:
    """The ROS domain a process with environment ``env`` joins (ROS 2's default is 0)."""
    return env.get('ROS_DOMAIN_ID', '').strip() or '0'


def foreign_graph(node: Any, spin_once: Callable[[float], None], topics: Iterable[str],
                  duration: float, own_names: Iterable[str] = (),
                  check: Callable[[], None] = lambda: None) -> str | None:
    """Spin ``node`` (which must have no publishers or subscriptions on ``topics``) for
    ``duration`` wall seconds, stopping early at the first sign of another graph: a node
    named as one of ``RUN_NODE_NAMES`` or ``own_names`` (besides ``node`` itself) or a
    publisher on one of ``topics``. Returns what was found, or None. ``check()`` runs every
    iteration and may raise (a stop signal)."""
    names = {*RUN_NODE_NAMES, *own_names}
    own = node.get_name()
    topics = [t if t.startswith('/') else '/' + t for t in topics]
    deadline = time.monotonic() + duration
    report_by: float | None = None        # once found: a moment more for the nodes' names
    while True:
        found, unnamed = _look(node, names, own, topics)
        now = time.monotonic()
        if found:
            if report_by is None:
                report_by = now + NAMES_WAIT
            if not unnamed or now >= report_by:
                return '; '.join(found).replace(_UNKNOWN, 'a node not yet named')
        check()
        remaining = (report_by if found else deadline) - now
        if remaining <= 0:
            return None
        spin_once(min(0.05, remaining))


#: Wall seconds to wait, once another graph is seen, for the names of its publishers' nodes.
NAMES_WAIT = 1.0
_UNKNOWN = '_NODE_NAME_UNKNOWN_'


def _look(node: Any, names: set[str], own: str, topics: list[str]) -> tuple[list[str], bool]:
    """What of another graph the node sees now, and whether a publisher's node is unnamed."""
    found = []
    counts: dict[str, int] = {}
    for name, namespace in node.get_node_names_and_namespaces():
        key = name if namespace == '/' else f'{namespace.rstrip("/")}/{name}'
        counts[key] = counts.get(key, 0) + 1
    for name in sorted(names):
        if counts.get(name, 0) - (1 if name == own else 0) > 0:
            found.append(f'node {name}')
    unnamed = False
    for topic in topics:
        publishers = sorted({info.node_name for info in node.get_publishers_info_by_topic(topic)})
        if publishers:
            unnamed = unnamed or _UNKNOWN in publishers
            found.append(f'publisher of {topic} ({", ".join(publishers)})')
    return found, unnamed
