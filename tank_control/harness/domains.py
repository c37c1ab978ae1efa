"""ROS_DOMAIN_IDs held by file locks (``flock``; a lock dies with its process), two kinds:

* a *claim* (``claim``, ``claimed``): ``<tmp>/tank_control_domains/<id>.lock``, a free domain
  taken for a while by one holder (a test session, a lockstep sweep run), so concurrent graphs
  on one host never see each other. Ids 1…100 are valid for LOCALHOST discovery on Linux. A
  domain is free when its lock is free and no DDS participant on this host is on it
  (``participants_on``: its RTPS ports are bound), whoever started it. A holder that runs the
  harness on its claimed domain may say so (``EXCLUSIVE_ENV``, ``exclusive_domain``): no run
  there then waits ``harness.discovery_time`` for a graph that was there before.
* a *run lock* (``lock_run``): ``<tmp>/tank_control_runs/domain-<id>.lock``, held by every ROS
  run of the harness for its whole length: one run at a time on a domain on this host, whoever
  claimed it (the runs of a test session all happen inside its claim).
"""
from __future__ import annotations

import errno
import fcntl
import os
import random
import socket
import tempfile
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import IO

LOCK_DIR = Path(tempfile.gettempdir()) / 'tank_control_domains'
RUN_LOCK_DIR = Path(tempfile.gettempdir()) / 'tank_control_runs'
DOMAIN_IDS = tuple(range(1, 101))
#: Set (to the id) by a holder of a domain's claim that runs the harness there: the domain is
#: its alone (``claim`` found no participant on it), so a run need not wait
#: ``harness.discovery_time`` for a graph that was there before (docs/harness.md, step 2).
EXCLUSIVE_ENV = 'TANK_CONTROL_EXCLUSIVE_DOMAIN'

# The RTPS well-known ports (DDSI-RTPS 2.5, 9.6.1.1): PB + DG·domain + d0 (discovery
# multicast), PB + DG·domain + d1 + PG·participant (discovery unicast of each participant).
_PB, _DG, _PG, _D0, _D1 = 7400, 250, 2, 0, 10
_PARTICIPANTS = (_DG - _D1) // _PG       # participant ids that fit below the next domain


def participants_on(domain_id: int) -> list[int]:
    """The RTPS discovery ports of ``domain_id`` that a process on this host holds (each a DDS
    participant, of Fast DDS or Cyclone DDS, whatever its discovery range; a participant on
    another host is not seen). Found by binding each port for a moment: instant, where DDS
    discovery of a running participant takes up to its 3 s announcement period."""
    base = _PB + _DG * domain_id
    ports = [base + _D0] + [base + _D1 + _PG * p for p in range(_PARTICIPANTS)]
    held = []
    for port in ports:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
            try:
                probe.bind(('0.0.0.0', port))
            except OSError as exc:
                if exc.errno == errno.EADDRINUSE:
                    held.append(port)
    return held


#: Fast DDS (2.x) participants that the harness starts (its recorder, the nodes) announce
#: themselves every 0.1 s for their first 4 s (``initialAnnouncements``), then every
#: :data:`ANNOUNCEMENT_PERIOD` s (Fast DDS's default: 3 s), so that the run's processes, which
#: join within a second or two of each other, find each other at once, and a node the harness
#: restarts is found within that period: a participant already on the domain answers a
#: newcomer only at its next announcement, and the nodes took 2.5 s longer to show in the
#: recorder's graph (bench/RESULTS.md, "A ROS run starts at once"). The lease (20 s) is
#: Fast DDS's default.
START_ANNOUNCEMENTS = (40, 0.1)
#: Seconds between a participant's announcements after its first 4 s (see above).
ANNOUNCEMENT_PERIOD = 0.5
PROFILES_ENV = 'FASTRTPS_DEFAULT_PROFILES_FILE'
_OWN_PROFILES = ('FASTRTPS_DEFAULT_PROFILES_FILE', 'FASTDDS_DEFAULT_PROFILES_FILE')


def start_profile_env(env: Mapping[str, str]) -> dict[str, str]:
    """``env`` with :data:`PROFILES_ENV` naming a profile of :data:`START_ANNOUNCEMENTS`
    (written to the temporary directory), unless ``env`` names a profile of its own (kept)
    or another middleware than Fast DDS."""
    out = dict(env)
    rmw = out.get('RMW_IMPLEMENTATION', '').strip()
    if any(out.get(name, '').strip() for name in _OWN_PROFILES) or (
            rmw and not rmw.startswith('rmw_fastrtps')):
        return out
    count, period = START_ANNOUNCEMENTS
    text = ('<?xml version="1.0" encoding="UTF-8" ?>\n'
            '<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">\n'
            '  <participant profile_name="tank_control_start" is_default_profile="true">\n'
            '    <rtps><builtin><discovery_config><initialAnnouncements>\n'
            f'      <count>{count}</count>\n'
            f'      <period>{_duration(period)}</period>\n'
            '    </initialAnnouncements>\n'
            f'    <leaseAnnouncement>{_duration(ANNOUNCEMENT_PERIOD)}</leaseAnnouncement>\n'
            '    </discovery_config></builtin></rtps>\n'
            '  </participant>\n</profiles>\n')
    path = Path(tempfile.gettempdir()) / f'tank_control_fastdds_start_{os.getuid()}.xml'
    try:
        if not path.exists() or path.read_text() != text:
            partial = path.with_name(f'{path.name}.{os.getpid()}')
            partial.write_text(text)
            os.replace(partial, path)           # whole or not at all for a concurrent run
    except OSError:
        return out                              # no profile: discovery as by default
    out[PROFILES_ENV] = str(path)
    return out


def _duration(seconds: float) -> str:
    """A Fast DDS XML duration of ``seconds`` [s]."""
    whole = int(seconds)
    return f'<sec>{whole}</sec><nanosec>{int(round((seconds - whole) * 1e9))}</nanosec>'


def local_only(env: Mapping[str, str]) -> bool:
    """A process with environment ``env`` discovers only participants on this host
    (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` and no ``ROS_STATIC_PEERS``): every
    participant it can meet holds ports that ``participants_on`` sees."""
    return (env.get('ROS_AUTOMATIC_DISCOVERY_RANGE', '').strip().upper() == 'LOCALHOST'
            and not env.get('ROS_STATIC_PEERS', '').strip())


def claim(candidates: Sequence[int] | None = None) -> tuple[int, IO[str]]:
    """Lock a free domain id (of ``candidates``, default ``DOMAIN_IDS``, in random order):
    its lock is free and no participant on this host is on it (``participants_on``).
    Returns it and the open lock file (close it to release)."""
    LOCK_DIR.mkdir(exist_ok=True)
    candidates = list(DOMAIN_IDS if candidates is None else candidates)
    random.SystemRandom().shuffle(candidates)
    in_use = []
    for domain_id in candidates:
        handle = open(LOCK_DIR / f'{domain_id}.lock', 'w')
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            handle.close()
            continue
        if participants_on(domain_id):     # a graph nobody claimed: started by hand
            handle.close()
            in_use.append(domain_id)
            continue
        return domain_id, handle
    raise RuntimeError(f'no free ROS_DOMAIN_ID among {len(candidates)} (locked in {LOCK_DIR}'
                       + (f'; with DDS participants on this host: '
                          f'{", ".join(map(str, sorted(in_use)))}' if in_use else '') + ')')


def claim_held(domain_id: int) -> bool:
    """Whether some process (this one included) holds the claim of ``domain_id``."""
    try:
        handle = open(LOCK_DIR / f'{domain_id}.lock')
    except OSError:
        return False
    with handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except OSError:
            return True
        return False


def exclusive_domain(env: Mapping[str, str]) -> bool:
    """A process with environment ``env`` is on a domain held exclusively: ``EXCLUSIVE_ENV``
    names its ROS_DOMAIN_ID and that domain's claim is held (by the one who set it)."""
    domain = domain_of(env)
    return (env.get(EXCLUSIVE_ENV, '').strip() == domain and domain.isdigit()
            and claim_held(int(domain)))


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
