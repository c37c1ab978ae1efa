"""Watch how many publishers of a topic this host's DDS participant knows of.

    python -P graph_watch.py TOPIC

prints ``<system time ns> <count>`` (flushed) at start and whenever the count changes,
checking every 0.1 s, until it is stopped. A remote publisher leaves the count when its
participant's lease expires or it leaves the graph, and comes back when it is discovered again.
"""
from __future__ import annotations

import sys
import time

import rclpy


def main(topic: str) -> int:
    rclpy.init()
    node = rclpy.create_node(f'graph_watch_{time.monotonic_ns()}')
    previous = None
    try:
        while rclpy.ok():
            rclpy.spin_once(node, timeout_sec=0.1)
            count = node.count_publishers(topic)
            if count != previous:
                print(f'{time.time_ns()} {count}', flush=True)
                previous = count
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1]))
