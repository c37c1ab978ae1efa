"""Who may use the dashboard (docs/dashboard.md, "Access"): the Host and Origin of every
request, and the per-start token a page must send with each write (a parameter set, a command).

A web page of another site can reach a server on 127.0.0.1 from the browser of the person who
opened it: its WebSocket carries the page's ``Origin`` (refused unless allowed), and under DNS
rebinding (a name of the other site resolving to 127.0.0.1) a ``Host`` that is not this
machine's (refused unless it is an IP address, localhost, this machine's name or the host of an
``allowed_origins`` entry). A page the dashboard served itself may read; it may write only with
the token of this start (logged by the node in its URL, ``?token=``), compared in constant time,
and never when ``read_only``. Refusals are counted by kind and logged at most once per
``LOG_PERIOD`` per kind (with the count since). No aiohttp or rclpy here.
"""
from __future__ import annotations

import hmac
import ipaddress
import re
import secrets
import socket
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from typing import Any
from urllib.parse import urlsplit

#: The entry of ``allowed_origins`` that stands for the dashboard's own page.
SELF = 'self'
#: Page messages that change something (need the token, refused when read-only).
WRITES = ('set', 'command')
#: Environment variable with a token chosen by whoever starts the node (``tank-control run
#: --dashboard`` prints its URL with it); unset or empty: a fresh random token per start.
TOKEN_ENV = 'TANK_CONTROL_DASHBOARD_TOKEN'
#: Shortest token accepted from ``TOKEN_ENV`` (characters).
MIN_TOKEN = 16
#: Seconds between two log lines of one kind of refusal (the count in between is logged).
LOG_PERIOD = 10.0
_ORIGIN = re.compile(r'^(https?)://(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9.-]+)(?::(\d{1,5}))?/?$')
_DEFAULT_PORT = {'http': 80, 'https': 443}


def is_loopback(host: str) -> bool:
    """``host`` (a listening address) reaches this machine only: 127.0.0.0/8, ::1, localhost."""
    if host.lower() == 'localhost':
        return True
    try:
        return ipaddress.ip_address(host.strip('[]')).is_loopback
    except ValueError:
        return False


def origin_key(text: str) -> str | None:
    """``scheme://host:port`` in lower case with the port made explicit, or None when ``text``
    is not an origin."""
    found = _ORIGIN.match(text.strip())
    if found is None:
        return None
    scheme, host, port = found.group(1).lower(), found.group(2).lower(), found.group(3)
    number = int(port) if port else _DEFAULT_PORT[scheme]
    return f'{scheme}://{host}:{number}' if 0 < number < 65536 else None


def origins_reason(entries: Iterable[str]) -> str | None:
    """One line naming ``allowed_origins`` and the allowed values, or None when all are fine."""
    bad = [e for e in entries if e != SELF and origin_key(e) is None]
    if not bad:
        return None
    return (f'allowed_origins: {bad[0]!r} is not an origin; allowed {SELF!r} or '
            'scheme://host[:port] with scheme http or https (e.g. http://192.168.1.5:8080)')


def derive_read_only(values: Mapping[str, Any], given: frozenset[str]) -> dict[str, Any]:
    """``read_only`` true on a host that is not loopback, unless the user set it."""
    if 'read_only' in given or is_loopback(str(values['host'])):
        return {}
    return {'read_only': True}


def start_token(environ: Mapping[str, str]) -> str:
    """This start's token: ``TOKEN_ENV`` if set (checked), else a fresh random one."""
    given = environ.get(TOKEN_ENV, '')
    if not given:
        return new_token()
    if len(given) < MIN_TOKEN or not re.fullmatch(r'[A-Za-z0-9_.~-]+', given):
        raise ValueError(f'{TOKEN_ENV}: allowed {MIN_TOKEN} or more characters of A-Z a-z 0-9 '
                         '_ . ~ - (unset: a random token per start)')
    return given


def new_token() -> str:
    """A random URL-safe token (32 characters, 192 bits)."""
    return secrets.token_urlsafe(24)


def _hostname(host_header: str) -> str | None:
    try:
        name = urlsplit('//' + host_header).hostname
    except ValueError:
        return None
    return name.lower() if name else None


class Access:
    """The checks of one dashboard start (thread-safe counters)."""

    def __init__(self, allowed_origins: Iterable[str], read_only: bool,
                 log: Callable[[str], None], token: str | None = None) -> None:
        entries = list(allowed_origins)
        self.allow_self = SELF in entries
        self.origins = {key for e in entries if e != SELF and (key := origin_key(e))}
        machine = socket.gethostname().lower()
        self.names = {'localhost', machine, machine.split('.')[0], machine + '.local'} | {
            _hostname(k.split('://', 1)[1]) or '' for k in self.origins}
        self.read_only = read_only
        self.token = token if token is not None else new_token()
        self._log = log
        self._lock = threading.Lock()
        self.refused: dict[str, int] = {}            # kind -> count
        self.last_reason = ''
        self._logged: dict[str, tuple[float, int]] = {}   # kind -> (when, count then)

    # ---------------------------------------------------------------- HTTP and WebSocket
    def http_reason(self, host_header: str | None, origin: str | None,
                    scheme: str = 'http') -> str | None:
        """Why a request with these headers is refused (one line), or None."""
        name = _hostname(host_header or '')
        if name is None:
            return self.refuse('host', 'refused: no valid Host header')
        if not self._host_ok(name):
            return self.refuse('host', f'refused: Host {host_header!r} is not this dashboard '
                               "(an IP address, localhost, this machine's name or a host of "
                               'allowed_origins)')
        if origin is None:
            return None            # not sent by a page of another site (curl, a navigation)
        key = origin_key(origin)
        if key is not None and key in self.origins:
            return None
        own = origin_key(f'{scheme}://{host_header}')
        if self.allow_self and key is not None and key == own:
            return None
        return self.refuse('origin', f'refused: Origin {origin[:100]!r} is not allowed '
                           '(parameter allowed_origins)')

    def _host_ok(self, name: str) -> bool:
        try:
            ipaddress.ip_address(name.strip('[]'))
            return True              # an address literal cannot be rebound to another host
        except ValueError:
            return name in self.names or name.endswith('.localhost')

    # ---------------------------------------------------------------- writes
    def write_reason(self, message: Mapping[str, Any]) -> str | None:
        """Why a page's ``set``/``command`` is refused (one line), or None."""
        if message.get('type') not in WRITES:
            return None
        if self.read_only:
            return self.refuse('read_only', 'refused: this dashboard is read-only (parameter '
                               'read_only): no parameter sets or commands')
        given = message.get('token')
        if not isinstance(given, str) or not given:
            return self.refuse('token', 'refused: no token (open the URL with ?token= '
                               'that dashboard_node logged)')
        if not hmac.compare_digest(given.encode('utf-8', 'replace'),
                                   self.token.encode('utf-8')):
            return self.refuse('token', 'refused: wrong token (open the URL with ?token= '
                               'that dashboard_node logged at its last start)')
        return None

    # ---------------------------------------------------------------- counting
    def refuse(self, kind: str, reason: str) -> str:
        """Count a refusal of ``kind``; log it unless one of that kind was logged less than
        ``LOG_PERIOD`` ago (then the next line says how many came in between)."""
        now = time.monotonic()
        with self._lock:
            count = self.refused[kind] = self.refused.get(kind, 0) + 1
            self.last_reason = reason
            when, then = self._logged.get(kind, (-LOG_PERIOD, 0))
            due = now - when >= LOG_PERIOD
            if due:
                self._logged[kind] = (now, count)
        if due:
            more = count - then - 1
            self._log(reason + (f' ({more} more {kind} refusals since the last line)'
                                if more > 0 else ''))
        return reason

    def counts(self) -> dict[str, int]:
        with self._lock:
            return dict(self.refused)
