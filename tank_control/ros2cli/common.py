"""Shared pieces of the verbs: the client node, graph waits, names, errors.

Every wait has a deadline: a missing node, topic or service ends the command
with a one-line error instead of hanging.
"""
from __future__ import annotations

import argparse
import os
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # rclpy is imported lazily: `ros2 run` and `--help` do not need it
    from rclpy.node import Node

DEFAULT_TIMEOUT = 5.0      # [s] waiting for a node, topic or service to be discovered
SPIN_TIME = 3.5            # [s] minimal discovery time for whole-graph listings: a
                           #     participant that missed our first announcements is found
                           #     at its next one, within Fast DDS's 3 s period (the daemon
                           #     counts it from its own start, so it costs its first call)
QUIET_TIME = 0.5           # [s] the graph counts as discovered after this long without change
EMPTY_WAIT = 3.5           # [s] discovery time granted while no other node is known: a
                           #     participant that missed our first announcements announces
                           #     itself again within Fast DDS's 3 s period
SETTLE_LIMIT = 6.0         # [s] longest discovery wait of a listing

#: Inside the ros2 daemon (``ros2cli/daemon.Daemon``, set by it): commands get a node of its
#: long-lived participant, and a listing counts the discovery time from the daemon's start.
DAEMON: Any = None


#: [s] longest the teardown of a done command (its output written) may take: rclpy's shutdown
#: and the DDS participant's deletion, both in ``client_node``, not at the interpreter's exit.
#: Past it the process exits anyway, with the command's status and a note on stderr — a `topic
#: echo --once` that printed its message must not hang in a middleware teardown that does not end.
TEARDOWN_LIMIT = 10.0
#: Set by the ``ros2`` command's entry point (``main.main``): only then does a command's end
#: arm the guard (never in the daemon, nor in a program that calls the verbs itself).
GUARD_TEARDOWN = False


class CliError(Exception):
    """A user-facing failure: printed as one line on stderr, exit code 1."""


class Interrupted(Exception):
    """SIGINT/SIGTERM shut rclpy down while waiting: a normal end, exit code 0."""


def exit_status(ended: BaseException | None) -> int:
    """The exit status of a command that returned (``ended`` None) or raised ``ended``: 0 for
    a requested stop (Ctrl-C, SIGTERM, a reader that went away), 1 for a failure."""
    if ended is None or isinstance(ended, (KeyboardInterrupt, Interrupted, BrokenPipeError)):
        return 0
    return 0 if type(ended).__name__ == 'ExternalShutdownException' else 1


def failure_line(ended: BaseException | None) -> str | None:
    """The one line on stderr for a command that raised ``ended`` (None: nothing to say)."""
    if isinstance(ended, CliError):
        return str(ended)
    if not isinstance(ended, Exception) or not exit_status(ended):
        return None
    return f'{type(ended).__name__}: {ended}'.splitlines()[0]   # never a traceback


def guard_teardown(ended: BaseException | None) -> None:
    """From now on the process ends within :data:`TEARDOWN_LIMIT` s: should the teardown
    still run then, a daemon thread flushes stdout, writes the command's failure line (if
    any) and a note on stderr, and exits with the command's status."""
    def watch() -> None:
        time.sleep(TEARDOWN_LIMIT)
        try:
            sys.stdout.flush()
        except Exception:   # noqa: BLE001 - a closed or broken stdout: nothing left to save
            pass
        line = failure_line(ended)
        os.write(2, ((f'{line}\n' if line else '') + 'ros2: the middleware did not shut down '
                     f'within {TEARDOWN_LIMIT:g} s; exiting without it\n').encode())
        os._exit(exit_status(ended))

    threading.Thread(target=watch, name='teardown-guard', daemon=True).start()


def add_timeout_argument(parser: argparse.ArgumentParser,
                         default: float = DEFAULT_TIMEOUT, what: str = 'the node') -> None:
    parser.add_argument('--timeout', type=float, default=default, metavar='SECONDS',
                        help=f'seconds to wait for {what} to be discovered (default {default:g})')


def add_spin_time_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--spin-time', type=float, default=SPIN_TIME, metavar='SECONDS',
                        help='minimal seconds of discovery before listing the graph '
                             f'(default {SPIN_TIME:g})')


def add_daemon_argument(parser: argparse.ArgumentParser) -> None:
    """``--no-daemon``: discover the graph in this process instead of asking the daemon."""
    parser.add_argument('--no-daemon', action='store_true',
                        help='do not use (or start) the ros2 daemon; discover the graph here')
    parser.set_defaults(daemon_verb=True)


@contextmanager
def client_node() -> Iterator['Node']:
    """rclpy (default context, with its SIGINT/SIGTERM handlers) and a hidden node
    ``_ros2cli_<pid>`` for one command; in the daemon, a node of its running participant."""
    import rclpy

    if DAEMON is not None:
        node = rclpy.create_node(
            DAEMON.node_name(), context=DAEMON.context, use_global_arguments=False,
            enable_rosout=False, start_parameter_services=False)
        try:
            yield node
        finally:
            node.destroy_node()
        return
    from rclpy.utilities import get_default_context

    rclpy.init(args=[])
    node = None
    ended: BaseException | None = None
    try:
        node = rclpy.create_node(
            f'_ros2cli_{os.getpid()}', use_global_arguments=False, enable_rosout=False,
            start_parameter_services=False)
        yield node
    except BaseException as exc:
        ended = exc
        raise
    finally:
        if GUARD_TEARDOWN:
            guard_teardown(ended)
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        # the participant is deleted here, under the guard, not at the interpreter's exit
        get_default_context().destroy()


def spin_until(node: 'Node', condition: Callable[[], bool], timeout: float | None) -> bool:
    """Spin ``node`` until ``condition()`` holds; False when ``timeout`` seconds pass first.

    ``timeout=None`` waits without a deadline (only for verbs a user stops with Ctrl-C).
    """
    from rclpy.executors import SingleThreadedExecutor

    if not node.context.ok():
        raise Interrupted()
    try:
        executor = SingleThreadedExecutor(context=node.context)
    except Exception:
        if not node.context.ok():      # the signal came between the check and here
            raise Interrupted() from None
        raise
    try:
        executor.add_node(node)
        deadline = None if timeout is None else time.monotonic() + timeout
        while not condition():
            if deadline is None:
                executor.spin_once(timeout_sec=0.05)
                continue
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return False
            executor.spin_once(timeout_sec=min(0.05, remaining))
        return True
    except Exception:
        # Ctrl-C/SIGTERM shuts the context down under a running spin: rclpy then fails to
        # create its wait set or timeout timer (RCLError) — a requested stop, not an error.
        if not node.context.ok():
            raise Interrupted() from None
        raise
    finally:
        if node.context.ok():
            executor.remove_node(node)


def graph_snapshot(node: 'Node') -> tuple:
    """Everything the listings show, to detect when discovery has settled (hidden names
    left out: command-line nodes come and go, each with its own services)."""
    return (tuple(sorted(n for n in node.get_fully_qualified_node_names() if not is_hidden(n))),
            tuple(sorted((n, tuple(t)) for n, t in node.get_topic_names_and_types()
                         if not is_hidden(n))),
            tuple(sorted((n, tuple(t)) for n, t in node.get_service_names_and_types()
                         if not is_hidden(n))))


def settle_graph(node: 'Node', spin_time: float = SPIN_TIME, quiet: float = QUIET_TIME,
                 snapshot_of: Callable[[], object] | None = None,
                 empty_wait: float = EMPTY_WAIT, limit: float = SETTLE_LIMIT) -> None:
    """Discover for at least ``spin_time`` s, then until nothing changed for ``quiet`` s.

    ``snapshot_of`` is what must stop changing (default: the whole graph). Discovery
    of a new participant can take more than a second on a loaded machine, so while
    no other node is known the wait goes on up to ``empty_wait`` s. Stops at
    ``limit`` s in a graph that keeps changing. In the daemon, discovery has run since
    the daemon started and the graph's last change is the daemon's: a graph that was
    complete is answered at once.
    """
    whole_graph = snapshot_of is None
    snapshot_of = snapshot_of or (lambda: graph_snapshot(node))
    start = time.monotonic()
    state: dict[str, Any] = {'snapshot': snapshot_of(), 'changed': start}
    if DAEMON is not None:
        start = min(start, DAEMON.started)
        if whole_graph:
            # a participant that missed the daemon's first announcements answers the next,
            # within Fast DDS's 3 s period: a young daemon's graph may lack it
            spin_time = max(spin_time, empty_wait)
            state['changed'] = DAEMON.graph_changed()

    def settled() -> bool:
        now = time.monotonic()
        snapshot = snapshot_of()
        if snapshot != state['snapshot']:
            state['snapshot'], state['changed'] = snapshot, now
        others = any(not is_hidden(n) for n in node.get_fully_qualified_node_names())
        return (now - start >= spin_time and now - state['changed'] >= quiet and
                (others or now - start >= empty_wait))

    spin_until(node, settled, limit)


def absolute_name(name: str) -> str:
    """``plant`` → ``/plant`` (names are resolved from the root namespace, like ros2cli)."""
    return name if name.startswith('/') else '/' + name


def split_node_name(full_name: str) -> tuple[str, str]:
    """``/ns/plant`` → (``plant``, ``/ns``); ``/plant`` → (``plant``, ``/``)."""
    namespace, _, name = absolute_name(full_name).rpartition('/')
    return name, namespace or '/'


def is_hidden(name: str) -> bool:
    """A name is hidden when any of its tokens starts with ``_`` (ROS 2 convention)."""
    return any(token.startswith('_') for token in name.split('/') if token)


def wait_for_node(node: 'Node', full_name: str, timeout: float) -> None:
    """Wait until ``full_name`` is in the graph, else raise ``CliError('Node not found')``."""
    if not spin_until(node, lambda: full_name in node.get_fully_qualified_node_names(), timeout):
        raise CliError(f"Node not found: '{full_name}' (waited {timeout:g} s)")


def call_service(node: 'Node', srv_type: type, name: str, request: object,
                 timeout: float, resend_after: float | None = None,
                 prime_with: object | None = None) -> Any:
    """Call a service with one deadline for discovery and the answer together;
    ``resend_after`` [s] for a read: ``nodes/services.answer`` (a response can be lost);
    ``prime_with`` a request without effect answered first, for a request sent once
    (``nodes/services.prime``)."""
    from tank_control.nodes.services import answer, prime

    deadline = time.monotonic() + timeout
    client = node.create_client(srv_type, name)
    try:
        if not spin_until(node, client.service_is_ready, timeout):
            raise CliError(f"Service '{name}' not available (waited {timeout:g} s)")
        if prime_with is not None and not prime(
                client, prime_with, lambda done, wait: spin_until(node, done, wait),
                max(0.0, deadline - time.monotonic())):
            raise CliError(f"No response from service '{name}' within {timeout:g} s")
        future = answer(client, request, lambda done, wait: spin_until(node, done, wait),
                        max(0.0, deadline - time.monotonic()), resend_after)
        if future is None:
            raise CliError(f"No response from service '{name}' within {timeout:g} s")
        if future.exception() is not None:
            raise CliError(f"Service '{name}' failed: {future.exception()}")
        return future.result()
    finally:
        node.destroy_client(client)
