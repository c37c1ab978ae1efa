"""Start-up and clean shutdown shared by every node's ``main()``."""
from __future__ import annotations

import signal
import sys
from collections.abc import Callable, Sequence
from types import FrameType

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.experimental import EventsExecutor
from rclpy.node import Node

#: Longest a spin_once waits [s]; the executor also wakes at once on shutdown.
SPIN_PERIOD = 1.0


def main(name: str, factory: Callable[[], Node], args: Sequence[str] | None = None) -> int:
    """A node's console entry point: :func:`run_node`, and exit status 2 with one line on
    stderr (``<name>: <reason>``) when its parameters are refused at start-up."""
    try:
        return run_node(factory, sys.argv if args is None else args)
    except ValueError as exc:           # ParameterError, ConfigError: one line, no traceback
        sys.stderr.write(f'{name}: {exc}\n')
        return 2


def run_node(factory: Callable[[], Node], args: Sequence[str] | None = None) -> int:
    """Init rclpy, build the node, spin until SIGINT/SIGTERM, shut down; return 0.

    rclpy's signal handlers cover SIGINT and SIGTERM: rcl shuts the context
    down (asynchronously) and spinning ends with ``ExternalShutdownException``
    (or the ``KeyboardInterrupt`` of SIGINT), both a clean stop; a signal that
    arrives while the node is still being built is one too. rclpy hands SIGINT
    on to Python's handler *after* its own, at a moment Python chooses — possibly
    during the clean-up or after this function has returned — so the
    Python-level handler raises ``KeyboardInterrupt`` only while the node is
    being built or spun, never during the clean-up.

    The node is spun by rclpy's ``EventsExecutor`` (C++; a third of the CPU per
    message of the ``SingleThreadedExecutor``, which rebuilds its wait set on
    every wake-up: 0.25 against 0.74 ms per hop in a bare three-process ring,
    bench/RESULTS.md, "Lockstep"). Its ``spin()`` busy-loops on
    a whole core and ignores SIGTERM in this rclpy build (3 of 3 tries with a
    100 Hz timer node), so it is driven by ``spin_once`` in a loop; the
    context's shutdown wakes it, so SIGINT and SIGTERM stop it within one callback.
    """
    running = [True]
    executor: EventsExecutor | None = None

    def interrupt(signum: int, frame: FrameType | None) -> None:
        if running[0]:
            raise KeyboardInterrupt

    signal.signal(signal.SIGINT, interrupt)
    rclpy.init(args=args)
    node: Node | None = None
    try:
        try:
            node = factory()
            executor = EventsExecutor()
            executor.add_node(node)
            # NOT executor.spin(): in this rclpy build EventsExecutor.spin() livelocks at
            # ~90 % CPU and ignores SIGTERM (16 of 17 tries, issue 18); spin_once works.
            while rclpy.ok():
                executor.spin_once(timeout_sec=SPIN_PERIOD)
        finally:
            running[0] = False
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        # A signal during start-up shuts the context down under the constructor:
        # that is a requested stop, not a crash. Anything else is a real error.
        if rclpy.ok():
            raise
    finally:
        # Out of the executor before it goes: destroying a node wakes its executor, and
        # waking an EventsExecutor that was shut down once busy-looped for good (a bench
        # process, bench/bench_lockstep.py, 1 in about 25 runs).
        if executor is not None and node is not None:
            executor.remove_node(node)
        if node is not None:
            node.destroy_node()
        if executor is not None:
            executor.shutdown()
        rclpy.try_shutdown()
    return 0
