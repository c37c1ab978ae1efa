"""dashboard_node's parameters, declared once (``param`` fields, docs/nodes.md "dashboard_node")."""
from __future__ import annotations

from dataclasses import dataclass

from tank_control.core.params import param


@dataclass(frozen=True)
class DashboardConfig:
    """Where the page is served, how often it is updated, what is kept and shown."""

    host: str = param('127.0.0.1', 'address the web server listens on (127.0.0.1: this '
                      'machine only; 0.0.0.0: every interface, without authentication)',
                      read_only=True)
    port: int = param(8080, 'TCP port of the web server (0: any free port, logged at start)',
                      min=0, max=65535, read_only=True)
    update_period: float = param(0.05, 'period of the batches of samples sent to each page '
                                 '(one WebSocket message per period)', unit='s, wall clock',
                                 min=0.01, max=2.0, read_only=True)
    buffer_messages: int = param(200_000, 'signal messages held for the pages (a page that '
                                 'connects gets them all; a page further behind is told how many '
                                 'it lost)', min=1000, max=10_000_000, read_only=True)
    nodes: tuple[str, ...] = param(('plant', 'controller', 'reference'),
                                   "nodes whose parameters, commands and state topics are "
                                   "shown, by name; ['*']: every node that offers parameter "
                                   'services', read_only=True)
    discovery_period: float = param(1.0, 'period of the look at the graph (nodes, their '
                                    'services and state topics)', unit='s, wall clock',
                                    min=0.1, max=60.0, read_only=True)
    runs_dir: str = param('', 'folder of past runs listed at /runs (tank-control run --out '
                          'folders, also nested up to 3 deep); empty: none, the page says how '
                          'to set it', read_only=True)
    allowed_origins: tuple[str, ...] = param(
        ('self',), "web origins (scheme://host[:port]) whose pages may use the dashboard; "
        "'self': the page the dashboard serves, under whatever address it is reached. A request "
        'from a page of another origin (its Origin header), or naming a host that is not an IP '
        "address, localhost, this machine's name or the host of an entry here (its Host "
        'header: DNS rebinding) is refused with 403', read_only=True)
    read_only: bool = param(
        False, 'serve trends and values without writes: parameter sets and commands are '
               'refused (default: false when host is a loopback address, 127.0.0.1 or '
               'localhost; true on any other host, unless set)', read_only=True)
