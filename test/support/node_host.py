"""Several of the project's nodes in one process, for a test that needs many of them at once
and tests what each node declares, not the process around it (a node process costs about a
second of CPU to start: imports, rclpy, DDS).

``python test/support/node_host.py NODES.json``: NODES.json is a list of
``[module, ros_arg, ...]`` (``module`` one of ``NODE_CLASSES``), each built with its own
``--ros-args`` (``-r __ns:=...``, ``-p``, ``--params-file``: rcl parses them as for a node
process of its own) and spun by one executor until SIGINT or SIGTERM. A node whose parameters
are refused ends the process with exit status 2 and the reason on stderr.
"""
from __future__ import annotations

import importlib
import json
import sys
from collections.abc import Sequence
from pathlib import Path

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

#: node module (tank_control.nodes) -> its node class
NODE_CLASSES = {'plant_node': 'PlantNode', 'controller_node': 'ControllerNode',
                'reference_node': 'ReferenceNode'}


def host_argv(path: Path, nodes: Sequence[Sequence[str]]) -> list[str]:
    """Write ``nodes`` (``[module, ros_arg, ...]`` each) to ``path``; the host's argv."""
    path.write_text(json.dumps([list(node) for node in nodes]))
    return [sys.executable, __file__, str(path)]


def main(path: str) -> int:
    specs = json.loads(open(path).read())
    rclpy.init()
    nodes = []
    executor = SingleThreadedExecutor()
    try:
        for module, *ros_args in specs:
            cls = getattr(importlib.import_module(f'tank_control.nodes.{module}'),
                          NODE_CLASSES[module])
            try:
                nodes.append(cls(cli_args=['--ros-args', *ros_args]))
            except ValueError as exc:
                sys.stderr.write(f'{module} {ros_args}: {exc}\n')
                return 2
            executor.add_node(nodes[-1])
        print(f'hosting {len(nodes)} nodes', flush=True)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        for node in nodes:
            executor.remove_node(node)
            node.destroy_node()
        executor.shutdown()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1]))
