"""plant_node (stub until its issue lands): starts, spins, exits 0 on SIGINT/SIGTERM."""
from __future__ import annotations

import sys

from rclpy.node import Node

from tank_control.nodes.runtime import run_node


def main(args: list[str] | None = None) -> int:
    """Console entry point plant_node."""
    return run_node(lambda: Node('plant'), args if args is not None else sys.argv)


if __name__ == '__main__':
    sys.exit(main())
