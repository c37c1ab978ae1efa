"""The small stand-in graph of the harness tests: a scenario file for the stand-in plant and
reference nodes (``standin_nodes.py``) with the real controller_node, and the command that
starts each node."""
from __future__ import annotations

import sys
from pathlib import Path

from tank_control.harness.scenario_file import Scenario, load_scenario

STANDINS = Path(__file__).parent / 'standin_nodes.py'

SCENARIO = """
plant:
  ros__parameters: {sample_time: 0.1}
controller:
  ros__parameters: {controller: pid, sample_time: 0.2, kp: 1.5, ti: 4.0, b: 0.5,
                    u_min: -1.0, u_max: 1.2}
reference:
  ros__parameters: {step_time: 1.0, step_value: 1.0}
harness:
  ros__parameters: {duration: 6.0, clock_mode: lockstep, startup_timeout: 60.0}
"""


def standin_command(node: str) -> list[str]:
    if node == 'controller':
        return [sys.executable, '-m', 'tank_control.nodes.controller_node']
    return [sys.executable, str(STANDINS), node]


def standin_scenario(path: Path, overrides: tuple[str, ...] = ()) -> Scenario:
    """The stand-ins have parameters of their own: only the harness section is checked."""
    return load_scenario(path, overrides, check_nodes=False)
