"""ROS_DOMAIN_IDs held by file locks, so concurrent graphs on one host never see each other.

A holder keeps ``<tmp>/tank_control_domains/<id>.lock`` locked (``flock``) while it uses the
domain; the lock dies with its process. Test sessions and lockstep sweep runs take their
domains here. Ids 1…100 are valid for LOCALHOST discovery on Linux.
"""
from __future__ import annotations

import fcntl
import random
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO

LOCK_DIR = Path(tempfile.gettempdir()) / 'tank_control_domains'
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
