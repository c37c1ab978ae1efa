"""The sticky-valve case over the real ROS 2 graph: plant_node applies the actuator faults
(actuator.stiction_s/j) exactly as the in-process loop does (lockstep trace equal to 1e-9), so
the verdicts of docs/monitoring.md hold for ROS runs; metrics.json carries loop_performance."""
from __future__ import annotations

import json

import numpy as np
from support import SCENARIOS

from tank_control.core.trace import Trace
from tank_control.harness.runner import run

DURATION = 300.0     # the first limit cycles (the full case: test_monitor_scenarios.py)


def test_sticky_valve_over_ros_equals_in_process(tmp_path, ros_env):
    path = SCENARIOS / 'monitor_sticky_valve.yaml'
    ros = run(path, tmp_path / 'ros', duration=DURATION, plots=False)
    run(path, tmp_path / 'ref', duration=DURATION, in_process=True, plots=False)
    a, b = Trace.read_csv(tmp_path / 'ros' / 'trace.csv'), Trace.read_csv(tmp_path / 'ref' / 'trace.csv')
    assert len(a) == len(b) == int(DURATION / 0.1) + 1
    for name in b.columns:
        np.testing.assert_allclose(a.columns[name], b.columns[name], rtol=0, atol=1e-9,
                                   err_msg=name)
    # the limit cycle has started: OP ramps over more than S − J, PV swings
    later = b.t > 120
    assert np.ptp(b['u.u'][later]) > 3.0 and np.ptp(b['y.y'][later]) > 2.0
    metrics = json.loads((tmp_path / 'ros' / 'metrics.json').read_text())
    assert metrics['loop_performance']['y'] == json.loads(
        (tmp_path / 'ref' / 'metrics.json').read_text())['loop_performance']['y']
    assert ros.metrics['loop_performance']['y']['samples'] == len(a)
