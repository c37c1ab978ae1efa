"""The shipped top-level scenarios (config/*.yaml, the ones the README starts by hand with
``ros2 run … --params-file``) are watchable: a hand-started plant keeps real time, while the
harness runs the same file as fast as possible."""
from __future__ import annotations

import pytest
from support import CONFIG

from tank_control.core import params_file
from tank_control.core.node_specs import PlantNode
from tank_control.core.params import config_from
from tank_control.harness.scenario_file import load_scenario, node_parameters

FILES = sorted(CONFIG.glob('*.yaml'))


@pytest.mark.parametrize('path', FILES, ids=[p.name for p in FILES])
def test_hand_started_plant_runs_at_real_time_and_the_harness_as_fast_as_possible(path):
    sections = params_file.read(path)
    values = params_file.node_values(sections, 'plant')
    node = config_from(PlantNode, {k: v for k, v in values.items()
                                   if k in ('clock_mode', 'real_time_factor')})
    assert node.clock_mode == 'wall' or node.real_time_factor == 1.0, (node.clock_mode,
                                                                       node.real_time_factor)
    harness = node_parameters(load_scenario(path))['plant']
    assert harness['clock_mode'] == 'lockstep' and harness['real_time_factor'] == 0.0
