"""A look at a ROS_DOMAIN_ID's graph while a run's nodes start: another run's node names or
publishers of the run's topics (``foreign_graph``). Steps and reasons: docs/harness.md ("How
a ROS run proceeds", steps 0 and 2). Times in wall seconds."""
from __future__ import annotations

import time
from collections.abc import Callable, Collection, Iterable
from typing import Any

#: Node names a run uses (the recorder's is ``recorder.RECORDER_NAME``).
RUN_NODE_NAMES = ('plant', 'controller', 'reference')


def foreign_graph(node: Any, spin_once: Callable[[float], None], topics: Iterable[str],
                  duration: float, own_names: Iterable[str] = (),
                  check: Callable[[], None] = lambda: None,
                  since: float | None = None, started: Collection[str] = (),
                  ready: Callable[[], bool] = lambda: True) -> str | None:
    """Spin ``node`` (which must have no publishers on ``topics``) until ``duration`` wall
    seconds after ``since`` (``time.monotonic()`` when its participant joined the domain;
    default now) have passed and ``ready()`` holds, stopping early at the first sign of
    another graph: a node named as one of ``RUN_NODE_NAMES`` or ``own_names`` (besides
    ``node`` itself) seen more often than this run started it, or a publisher on one of
    ``topics`` whose node this run did not start. ``started``: the names of the nodes this
    run started, one each (its own nodes, which may be coming up meanwhile: a second node of
    such a name is another graph's; the first is taken for the run's own until the second
    shows). Returns what was found, or None. ``check()`` runs every iteration and may raise
    (a stop signal, a node that died, a time-out). DDS discovers in threads of its own, so
    the time between ``since`` and the call counts (the harness does other work in it).
    A publisher whose node is not named yet is waited for (up to :data:`NAMES_WAIT` once the
    rest is done): it may be one of the run's own nodes, whose name comes a moment later."""
    names = {*RUN_NODE_NAMES, *own_names, *started}
    own = node.get_name()
    topics = [t if t.startswith('/') else '/' + t for t in topics]
    deadline = (time.monotonic() if since is None else since) + duration
    report_by: float | None = None        # once found: a moment more for the nodes' names
    unnamed_since: float | None = None    # done but for unnamed publishers: since when
    while True:
        found, unnamed = _look(node, names, own, set(started), topics)
        now = time.monotonic()
        if found:
            if report_by is None:
                report_by = now + NAMES_WAIT
            if not unnamed or now >= report_by:
                return '; '.join(found + [f'publisher of {t} (a node not yet named)'
                                          for t in unnamed])
        elif now >= deadline and ready():
            if not unnamed:
                return None
            unnamed_since = now if unnamed_since is None else unnamed_since
            if now - unnamed_since >= NAMES_WAIT:
                return '; '.join(f'publisher of {t} (a node not yet named)' for t in unnamed)
        check()
        spin_once(min(0.05, deadline - now) if not found and now < deadline else 0.05)


#: Wall seconds to wait, once another graph is seen, for the names of its publishers' nodes.
NAMES_WAIT = 1.0
_UNKNOWN = '_NODE_NAME_UNKNOWN_'


def _look(node: Any, names: set[str], own: str, started: set[str],
          topics: list[str]) -> tuple[list[str], list[str]]:
    """What of another graph the node sees now, and the topics with a publisher whose node is
    not named yet."""
    found = []
    counts: dict[str, int] = {}
    for name, namespace in node.get_node_names_and_namespaces():
        key = _key(name, namespace)
        counts[key] = counts.get(key, 0) + 1
    for name in sorted(names):
        if counts.get(name, 0) - (name == own) - (name in started) > 0:
            found.append(f'node {name}')
    unnamed = []
    for topic in topics:
        nodes = [info.node_name if info.node_name == _UNKNOWN
                 else _key(info.node_name, getattr(info, 'node_namespace', '/'))
                 for info in node.get_publishers_info_by_topic(topic)]
        if _UNKNOWN in nodes:
            unnamed.append(topic)
        foreign = sorted({name for name in nodes if name != _UNKNOWN and (
            name not in started or counts.get(name, 0) > 1)})
        if foreign:
            found.append(f'publisher of {topic} ({", ".join(foreign)})')
    return found, unnamed


def _key(name: str, namespace: str) -> str:
    """``plant`` for /plant, ``ns/plant`` for /ns/plant (how the run's names are written)."""
    return name if namespace in ('/', '') else f'{namespace.strip("/")}/{name}'
