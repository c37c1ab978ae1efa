"""The five shipped monitoring cases (config/scenarios/monitor_*.yaml) over the real ROS 2 graph:
each file run as shipped (lockstep, real_time_factor 0), and the live verdict controller_node
publishes on ``~/loop_performance`` at the end of the run (recorded in run.mcap) is the one
docs/monitoring.md states ("Live: controller_node"). The monitor runs with its defaults: the
loop's dead time comes from the process model the controller carries (``tuning.*``)."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from support.mcap import read_mcap

from tank_control.core import scenario
from tank_control.core.trace import Trace
from tank_control.harness.runner import run

REPO = Path(__file__).resolve().parents[2]
SCENARIOS = REPO / 'config' / 'scenarios'

#: docs/monitoring.md, the live table: the verdict over the last monitor.window (600 s)
LIVE = {
    'well_tuned': 'good',
    'sluggish': 'retune (sluggish: Harris index',
    'aggressive': 'retune (oscillating, period',
    'sticky_valve': 'valve: stiction suspected — do not retune',
    'saturated': 'saturated ',
    'minimum_variance': 'good',
}


@pytest.mark.parametrize('name', sorted(LIVE))
def test_live_verdict_of_each_shipped_case_over_ros(tmp_path: Path, ros_env, name: str) -> None:
    path = SCENARIOS / f'monitor_{name}.yaml'
    sections = scenario.sections_of(path)
    assert not any(k.startswith('monitor.') for k in sections['controller'])   # defaults
    result = run(path, tmp_path / 'ros', env=ros_env, plots=False)
    assert result.metrics['complete'], result.metrics['reason']
    recorded = read_mcap(tmp_path / 'ros' / 'run.mcap')
    reports = [json.loads(m.data) for m in recorded.get('/controller/loop_performance', [])]
    assert reports, sorted(recorded)
    last = reports[-1]
    duration = sections['harness']['duration']
    assert last['output'] == 'y' and last['time'] >= duration - 10.0, last['time']
    assert last['verdict'].startswith(LIVE[name]), last['verdict']
    # the dead time the controller knows of its process: tuning.dead_time of the file
    ts, dead_time = sections['controller']['sample_time'], sections['controller']['tuning.dead_time']
    assert last['dead_time'] == dead_time and 'tuning.*' in last['dead_time_source']
    assert last['dead_time_samples'] == math.floor(dead_time / ts + 1e-9) + 1
    assert last['manual_pct'] == 0.0 and last['fail_safe_pct'] == 0.0
    if name == 'saturated':
        # the time at a limit over the window, counted here from the recorded trace
        trace = Trace.read_csv(tmp_path / 'ros' / 'trace.csv')
        window = (trace.t > last['time'] - 600.0) & (trace.t <= last['time'])
        u = trace['u.u'][window][::int(round(ts / sections['plant']['sample_time']))]
        at_limit = 100.0 * float(np.mean(np.abs(u) >= 50.0 - 1e-6))
        assert last['saturation_pct'] == pytest.approx(at_limit, abs=1.0)
        assert last['verdict'] == f'saturated {last["saturation_pct"]:.0f} % of the time'
