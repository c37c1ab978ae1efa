"""Two hosts on one machine: Linux network namespaces joined by a veth pair.

``two_hosts(tag)`` creates namespaces ``<tag>_plant`` and ``<tag>_station`` (names unique per
test session), a veth pair with one end in each (``10.a.b.1/30`` and ``10.a.b.2/30``, a and b
random per call) and brings the ends and each namespace's loopback up. On leaving — also when
the body raised — every process still inside a namespace is killed (by pid, from
``ip netns pids``: they can only be this test's) and both namespaces are deleted, which
destroys the veth pair. The body starts once both ends are operationally up (see
``wait_running``). Needs root (CAP_NET_ADMIN); without it ``NetnsUnavailable`` says so.

Each namespace has its own addresses, so Fast DDS gives the processes in it a host id of its
own (an MD5 of the host name and the IPv4 addresses) and talks to the other namespace over
UDP on the veth, as between two machines, not over shared memory.
"""
from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass


class NetnsUnavailable(RuntimeError):
    """Network namespaces cannot be created here (not root, no ``ip``)."""


@dataclass(frozen=True)
class Host:
    """One namespace with its end of the veth pair."""

    netns: str
    device: str
    address: str

    def exec(self, argv: Sequence[str]) -> list[str]:
        """``argv`` run inside this namespace (``ip netns exec`` execs it: same pid)."""
        return ['ip', 'netns', 'exec', self.netns, *argv]


@dataclass(frozen=True)
class TwoHosts:
    """The plant's host and the operator station, one veth link between them."""

    plant: Host
    station: Host

    def set_link(self, up: bool) -> None:
        """Take the plant's end of the link down (both directions stop) or up again."""
        ip('-n', self.plant.netns, 'link', 'set', self.plant.device, 'up' if up else 'down')


def ip(*args: str) -> str:
    """Run ``ip ARGS``; ``NetnsUnavailable`` with its message when it fails."""
    try:
        done = subprocess.run(['ip', *args], capture_output=True, text=True, timeout=30)
    except FileNotFoundError:
        raise NetnsUnavailable('the `ip` command (iproute2) is not installed') from None
    if done.returncode != 0:
        raise NetnsUnavailable(f'`ip {" ".join(args)}` failed: {done.stderr.strip()}')
    return done.stdout


def operstate(host: Host) -> str:
    """The kernel's operational state of the host's veth end (``UP`` once it carries traffic)."""
    return json.loads(ip('-j', '-n', host.netns, 'link', 'show', 'dev', host.device))[0]['operstate']


def wait_running(host: Host, timeout: float = 10.0) -> None:
    """Until the veth end is operationally up (IFF_RUNNING). The kernel reports a carrier change
    up to a second after ``link set up``, and Fast DDS lists only running interfaces, once,
    when a participant starts: a process started before then would never use the link."""
    deadline = time.monotonic() + timeout
    while operstate(host) != 'UP':
        if time.monotonic() > deadline:
            raise NetnsUnavailable(f'{host.device} in {host.netns} not up after {timeout:g} s: '
                                   f'{operstate(host)}')
        time.sleep(0.02)             # a kernel state without an event to wait on here


def _kill_inside(netns: str) -> None:
    try:
        pids = ip('netns', 'pids', netns).split()
    except NetnsUnavailable:
        return
    for pid in pids:
        try:
            os.kill(int(pid), signal.SIGKILL)
        except (ProcessLookupError, ValueError):
            pass


@contextmanager
def two_hosts(tag: str) -> Iterator[TwoHosts]:
    """The namespaces and their link for the ``with`` body; removed afterwards in any case."""
    if os.geteuid() != 0:
        raise NetnsUnavailable(f'creating network namespaces needs root (CAP_NET_ADMIN); '
                               f'this test runs as uid {os.geteuid()}')
    rng = random.SystemRandom()
    net = f'10.{rng.randrange(16, 250)}.{rng.randrange(0, 64) * 4}'
    short = tag[-8:]
    hosts = TwoHosts(Host(f'{tag}_plant', f'tcp{short}', f'{net}.1'),
                     Host(f'{tag}_station', f'tcs{short}', f'{net}.2'))
    created: list[str] = []
    try:
        for host in (hosts.plant, hosts.station):
            ip('netns', 'add', host.netns)
            created.append(host.netns)
        ip('link', 'add', hosts.plant.device, 'netns', hosts.plant.netns, 'type', 'veth',
           'peer', 'name', hosts.station.device, 'netns', hosts.station.netns)
        for host in (hosts.plant, hosts.station):
            ip('-n', host.netns, 'addr', 'add', f'{host.address}/30', 'dev', host.device)
            ip('-n', host.netns, 'link', 'set', 'lo', 'up')
            ip('-n', host.netns, 'link', 'set', host.device, 'up')
        for host in (hosts.plant, hosts.station):
            wait_running(host)
        yield hosts
    finally:
        for netns in created:
            _kill_inside(netns)
        for netns in created:
            try:
                ip('netns', 'del', netns)
            except NetnsUnavailable:
                pass
