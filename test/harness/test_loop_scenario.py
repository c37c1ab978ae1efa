"""core/scenario.py: ROS 2 params files → core objects → the in-process run."""
from __future__ import annotations

import numpy as np
import pytest
from support import CONFIG

from tank_control.core import params_file
from tank_control.core.scenario import build, run_in_process

CONFIGS = sorted((CONFIG).glob('*.yaml'))


def test_wildcard_and_node_sections_merge_as_ros_does(tmp_path):
    path = tmp_path / 's.yaml'
    path.write_text("""
/**:
  ros__parameters: {clock_mode: lockstep, seed: 3}
/plant:
  ros__parameters:
    plant: ipdt
    seed: 5
    lockstep: {resend_period: 0.2}
/**/reference:
  ros__parameters:
    setpoint: {channels: ['y'], y: {value: 1e-3}}
""")
    params = params_file.read(path)
    assert params_file.node_values(params, 'plant') == {
        'clock_mode': 'lockstep', 'seed': 5, 'plant': 'ipdt', 'lockstep.resend_period': 0.2}
    assert params['reference']['setpoint.y.value'] == 0.001      # 1e-3 is a float, as in ROS
    assert params['/**'] == {'clock_mode': 'lockstep', 'seed': 3}


def test_an_unquoted_y_channel_is_rejected_as_ros_would_read_it(tmp_path):
    path = tmp_path / 's.yaml'
    path.write_text("reference:\n  ros__parameters:\n    setpoint.channels: [y]\n")
    params = params_file.read(path)
    assert params['reference']['setpoint.channels'] == [True]
    with pytest.raises(ValueError, match="quote names such as 'y'"):
        build({'reference': params['reference']})


@pytest.mark.parametrize('config', CONFIGS, ids=[c.stem for c in CONFIGS])
def test_shipped_scenarios_run_in_process_and_reach_their_final_setpoints(config):
    params = params_file.read(config)
    trace = run_in_process(config)
    duration = params['harness']['duration']
    ts = params['plant']['sample_time']
    assert len(trace) == round(duration / ts) + 1
    for name in (n for n in trace.names if n.startswith('r.')):
        y = trace['y.' + name[2:]]
        assert np.all(np.isfinite(y))
        # settled within 1 % of the final setpoint at the end of the run
        assert abs(y[-1] - trace[name][-1]) <= 0.01 * max(abs(trace[name][-1]), 1.0), name


def test_the_001_ramp_cuts_the_zn_overshoot_of_the_step(tmp_path):
    """[DeadTimeNotes] Fig. 1.15: the same ZN PID overshoots far less with a 25 s setpoint ramp."""
    step = run_in_process(CONFIG / 'fopdt_zn.yaml')
    ramp = run_in_process(CONFIG / 'fopdt_zn_ramp.yaml')
    over_step = step['y.y'].max() / 100.0 - 1.0
    over_ramp = ramp['y.y'].max() / 100.0 - 1.0
    assert over_step > 0.3 and over_ramp < over_step / 4
