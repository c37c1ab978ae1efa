"""Start-up and clean shutdown shared by every node's ``main()``."""
from __future__ import annotations

from collections.abc import Callable, Sequence

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node


def run_node(factory: Callable[[], Node], args: Sequence[str] | None = None) -> int:
    """Init rclpy, build the node, spin until SIGINT/SIGTERM, shut down; return 0.

    rclpy's default signal handlers cover SIGINT and SIGTERM: spinning ends with
    ``KeyboardInterrupt`` or ``ExternalShutdownException``, both a clean stop;
    a signal that arrives while the node is still being built is one too.
    """
    rclpy.init(args=args)
    node: Node | None = None
    try:
        node = factory()
        rclpy.spin(node)
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
