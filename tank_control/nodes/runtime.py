"""Start-up and clean shutdown shared by every node's ``main()``."""
from __future__ import annotations

import signal
import sys
from collections.abc import Callable, Sequence
from types import FrameType

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node


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
    """
    running = [True]

    def interrupt(signum: int, frame: FrameType | None) -> None:
        if running[0]:
            raise KeyboardInterrupt

    signal.signal(signal.SIGINT, interrupt)
    rclpy.init(args=args)
    node: Node | None = None
    try:
        try:
            node = factory()
            rclpy.spin(node)
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
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
