"""A look at a ROS_DOMAIN_ID's graph before a run starts anything on it: another run's node
names or publishers of the run's topics (``foreign_graph``). Steps and reasons:
docs/harness.md ("How a ROS run proceeds", step 0). Times in wall seconds."""
from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from typing import Any

#: Node names a run uses (the recorder's is ``recorder.RECORDER_NAME``).
RUN_NODE_NAMES = ('plant', 'controller', 'reference')


def foreign_graph(node: Any, spin_once: Callable[[float], None], topics: Iterable[str],
                  duration: float, own_names: Iterable[str] = (),
                  check: Callable[[], None] = lambda: None,
                  since: float | None = None) -> str | None:
    """Spin ``node`` (which must have no publishers or subscriptions on ``topics``) until
    ``duration`` wall seconds after ``since`` (``time.monotonic()`` when its participant
    joined the domain; default now), stopping early at the first sign of another graph: a
    node named as one of ``RUN_NODE_NAMES`` or ``own_names`` (besides ``node`` itself) or a
    publisher on one of ``topics``. Returns what was found, or None. ``check()`` runs every
    iteration and may raise (a stop signal). DDS discovers in threads of its own, so the
    time between ``since`` and the call counts (the harness does other work in it)."""
    names = {*RUN_NODE_NAMES, *own_names}
    own = node.get_name()
    topics = [t if t.startswith('/') else '/' + t for t in topics]
    deadline = (time.monotonic() if since is None else since) + duration
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
