"""A free TCP port on loopback for a test's server (OPC UA, the dashboard)."""
from __future__ import annotations

import random
import socket
from pathlib import Path

#: lowest port tried; below it are well-known and registered services' usual ports
LOWEST = 20000


def _ephemeral_low() -> int:
    """The lowest port the kernel hands out for outgoing connections (Linux default 32768)."""
    try:
        return int(Path('/proc/sys/net/ipv4/ip_local_port_range').read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return 32768


def free_port() -> int:
    """A TCP port on 127.0.0.1 that is free now, drawn at random below the kernel's ephemeral
    range: a port the kernel picks itself (``bind(0)``) comes from that range, where any
    client connection of the busy machine may take it before the test's server binds it
    (seen as "address already in use"); drawn at random, parallel test workers rarely try the
    same one, and a port found taken is skipped."""
    top = max(_ephemeral_low(), LOWEST + 1000)
    draw = random.SystemRandom()
    for _ in range(500):
        port = draw.randrange(LOWEST, top)
        with socket.socket() as s:
            try:
                s.bind(('127.0.0.1', port))
            except OSError:
                continue
            return port
    raise RuntimeError(f'no free TCP port on 127.0.0.1 in [{LOWEST}, {top})')
