"""Start-up and clean shutdown shared by every node's ``main()``."""
from __future__ import annotations

import atexit
import faulthandler
import gc
import os
import signal
import sys
import threading
from collections.abc import Callable, Sequence
from pathlib import Path
from types import FrameType
from typing import Any

import rclpy
import yaml
from rclpy._rclpy_pybind11 import RCLError
from rclpy.executors import Executor, ExternalShutdownException
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from tank_control.core import params_file, ros_yaml

#: Longest a spin_once waits [s]: an idle node notices SIGINT/SIGTERM within it (run_node).
SPIN_PERIOD = 0.1


def main(name: str, factory: Callable[[], Node], args: Sequence[str] | None = None) -> int:
    """A node's console entry point: :func:`run_node`, and exit status 2 with one line on
    stderr (``<name>: <reason>``) when its parameters are refused at start-up, a
    ``--params-file`` cannot be read or is not valid YAML (file, line and column), or rcl
    refuses the command line."""
    if args is None:
        # the process ends with the node: nothing it made needs collecting at the
        # interpreter's shutdown (a stop 0.05 s sooner)
        atexit.register(gc.freeze)
    args = list(sys.argv if args is None else args)
    own = args[1:args.index('--ros-args')] if '--ros-args' in args else args[1:]
    if '-h' in own or '--help' in own:
        print(node_help(name))
        return 0
    try:
        reason = params_files_reason(args)
        if reason:
            raise ValueError(reason)
        return run_node(factory, args)
    except ValueError as exc:           # ParameterError, ConfigError: one line, no traceback
        sys.stderr.write(f'{name}: {exc}\n')
        return 2
    except RCLError as exc:             # rcl refused the arguments (e.g. a bad remapping)
        sys.stderr.write(f'{name}: {str(exc).splitlines()[0]}\n')
        return 2


NODE_HELP = {
    'plant_node': ('plant', 'The plant simulation selected by the parameter `plant` ({kinds}) '
                   'and the clock master of the loop.'),
    'controller_node': ('controller', 'The controller selected by the parameter `controller` '
                        '({kinds}).'),
    'reference_node': ('reference', 'Setpoint and disturbance schedules.'),
    'dashboard_node': ('dashboard', 'A web page on localhost (parameter port, default 8080) '
                       'with the graph\'s trends, parameters and margins.'),
    'opcua_bridge_node': ('opcua_bridge', 'An OPC UA server\'s variables as the loop\'s plant: '
                          'measurement from, manipulated to the server (docs/opcua.md).'),
    'signal_bridge_node': ('signal_bridge', 'Real sensors and actuators as the loop\'s plant: '
                           'std_msgs/Float64 and sensor_msgs scalar topics to and from the '
                           'measurement and manipulated channels (docs/signal_bridge.md).'),
}

#: a node documented elsewhere than docs/nodes.md: (its page, its example file)
NODE_DOCS = {'opcua_bridge_node': ('docs/opcua.md', 'docs/opcua/bridge.yaml'),
             'signal_bridge_node': ('docs/signal_bridge.md',
                                    'docs/signal_bridge/example.yaml')}


def _kind_names(node: str) -> str:
    """The kinds a plant or controller node can run (built-in and installed plugins)."""
    if node == 'plant':
        from tank_control.core.plants.kinds import registry as plants
        return ', '.join(plants.KINDS)
    from tank_control.core.control.kinds import registry as controllers
    return ', '.join(controllers.KINDS)


def node_help(name: str) -> str:
    """``<node> --help``: what the node is, how it takes its parameters, an example."""
    node, what = NODE_HELP[name]
    if '{kinds}' in what:
        what = what.replace('{kinds}', _kind_names(node))
    docs, example = NODE_DOCS.get(name, ('docs/nodes.md', 'config/fopdt_autotune.yaml'))
    kinds = ('; every kind with its origin: tank-control list --kinds'
             if node in ('plant', 'controller') else '')
    return (f'usage: {name} [-h] [--ros-args [--params-file FILE] [-p NAME:=VALUE] '
            f'[-r __node:=NAME] ...]\n\n{what}\n\n'
            f'Parameters come from ROS 2 params files and -p (a -p does not override the '
            f'node\'s own section of a params file); on a running node: ros2 param list '
            f'/{node}, ros2 param describe /{node} NAME. All of them: {docs}{kinds}.\n\n'
            f'example:\n  ros2 run tank_control {name} --ros-args --params-file '
            f'{example}')


def params_files_reason(args: Sequence[str]) -> str | None:
    """'' or why a ``--params-file`` among the ROS arguments cannot be used: unreadable, or
    not valid YAML (``FILE:LINE:COLUMN: …``); rcl would say only "Couldn't parse params file"
    in a traceback. What the file holds is checked by the node, parameter by parameter."""
    for name in params_file.ros_params_files(args):
        path = Path(name)
        try:
            text = path.read_text()
        except OSError as exc:
            return f'--params-file {path}: cannot read ({exc.strerror})'
        try:
            ros_yaml.load(text)
        except yaml.YAMLError as exc:
            return params_file.yaml_error(str(path), exc)
    return None


NAME_CHECK_PERIOD = 2.0
"""[s] of wall time between two looks for another node of the same name."""


def duplicate_name_problem(node: Node) -> str:
    """'' or why the graph holds another node with ``node``'s name (one line for a log)."""
    namespace = node.get_namespace()
    key = (node.get_name(), namespace if namespace.endswith('/') else namespace + '/')
    count = sum(1 for name, ns in node.get_node_names_and_namespaces()
                if (name, ns if ns.endswith('/') else ns + '/') == key)
    if count <= 1:
        return ''
    return (f'{count} nodes named {node.get_fully_qualified_name()} on this graph '
            '(ROS_DOMAIN_ID ' + os.environ.get('ROS_DOMAIN_ID', '0') + '): their '
            'topics, parameters and services mix; stop the other one, or start this '
            'one with -r __node:=<another name> or another ROS_DOMAIN_ID')


class NameWatch:
    """Reports another node with this node's name on the graph: two ``plant``s on one
    ROS_DOMAIN_ID mix their topics, parameter services and diagnostics. Looked for every
    :data:`NAME_CHECK_PERIOD` wall seconds (a steady-clock timer: also while a lockstep
    or sim clock stands still); logged as ERROR once each time it starts, and once when it
    ends; a node with a method ``on_name_conflict(problem)`` is told when it starts (the
    controller ends a running auto-tune test with it as the reason). ``problem`` is the
    current text ('' if none) for a node's diagnostics."""

    def __init__(self, node: Node) -> None:
        from tank_control.nodes.clock import steady_clock
        self.node = node
        self.problem = ''
        self.timer = node.create_timer(NAME_CHECK_PERIOD, self.check, clock=steady_clock())

    def check(self) -> None:
        problem = duplicate_name_problem(self.node)
        if problem and not self.problem:
            self.node.get_logger().error(problem)
            on_conflict = getattr(self.node, 'on_name_conflict', None)
            if on_conflict is not None:
                on_conflict(problem)
        elif self.problem and not problem:
            self.node.get_logger().info(f'{self.node.get_fully_qualified_name()} is the only '
                                        'node of its name again')
        self.problem = problem


def run_node(factory: Callable[[], Node], args: Sequence[str] | None = None) -> int:
    """Init rclpy, build the node, spin until SIGINT/SIGTERM, shut down; return 0.

    SIGINT and SIGTERM are handled here, not by rclpy: rclpy's handlers shut the
    context down from another thread at once, so a callback that was running (a busy
    lockstep controller publishing its answer) failed with "publisher's context is
    invalid" and a [FATAL] traceback. Here a signal only sets a flag (Python runs the
    handler between two bytecodes of the main thread, never inside rcl); the loop
    below stops after the callback in progress, then the node leaves the executor, is
    destroyed, and the context is shut down last — a clean stop with exit status 0,
    also for a signal that arrives while the node is being built.

    The node is spun by rclpy's ``EventsExecutor`` (C++; a third of the CPU per
    message of the ``SingleThreadedExecutor``, which rebuilds its wait set on
    every wake-up: 0.25 against 0.74 ms per hop in a bare three-process ring,
    bench/RESULTS.md, "Lockstep"). NOT ``EventsExecutor.spin()``: in this rclpy build
    it livelocks at ~90 % CPU and ignores SIGTERM (16 of 17 tries, bench/RESULTS.md),
    so it is driven by ``spin_once`` in a loop. A spin_once blocked in C++ does not run
    Python's signal handlers, so it waits at most :data:`SPIN_PERIOD`: an idle node
    stops within that, a busy one after its current callback.
    """
    # A crash, or a SIGABRT sent to a node that does not stop, writes every thread's Python
    # stack to the log (stderr) — also while the main thread is blocked in C++.
    faulthandler.enable()
    stop = _StopFlag()
    executor: Executor | None = None
    with stop:
        rclpy.init(args=None if args is None else list(args),
                   signal_handler_options=SignalHandlerOptions.NO)
        node: Node | None = None
        try:
            if not stop.requested:
                node = factory()
                NameWatch(node)
                executor = EventsExecutor()
                executor.add_node(node)
                quiet_collector()
                while not stop.requested and rclpy.ok():
                    executor.spin_once(timeout_sec=SPIN_PERIOD)
        except ExternalShutdownException:
            pass
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


def quiet_collector() -> None:
    """Start-up is over: everything it built (modules, the node, its model) leaves the
    garbage collector's generations (``gc.freeze``), so a collection walks only the objects
    made since. Otherwise a collection of the older generations walks them all and stops the
    process for milliseconds (bench/RESULTS.md, "Wall mode": up to 10 ms in a node, 130 ms in
    the harness, within a 100 Hz loop). Reference counting still frees them when unused."""
    gc.collect()
    gc.freeze()


class _StopFlag:
    """SIGINT and SIGTERM set ``requested`` while active (the previous handlers are put
    back on exit). Installed from the main thread only, as Python requires."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.requested = False
        self._previous: dict[int, Any] = {}

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        self.requested = True

    def __enter__(self) -> _StopFlag:
        if threading.current_thread() is threading.main_thread():
            for sig in self.SIGNALS:
                self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc: object) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous.clear()
