"""The live verdict of the six shipped monitoring cases (config/scenarios/monitor_*.yaml): the one
controller_node publishes on ``~/loop_performance`` is the one docs/monitoring.md states ("Live:
controller_node"). The monitor runs with its defaults: the loop's dead time comes from the
process model the controller carries (``tuning.*``).

Every case: the node's own monitor (``nodes/loop_performance.LoopPerformance``, the object
controller_node feeds after each sample) fed the in-process loop's samples. Two cases over the
real ROS 2 graph (lockstep, real_time_factor 0) — the sticky valve (plant_node's actuator faults:
its trace equal to the in-process one to 1e-9, and the same loop_performance in metrics.json)
and the saturated loop (a controller slower than the plant) — where the last summary published
is the one the replay computes: what the other four would publish over ROS too, since a lockstep
run's samples are the in-process loop's (test_scenarios_ros.py and the other lockstep tests)."""
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
OVER_ROS = ('sticky_valve', 'saturated')


class _Publisher:
    def __init__(self) -> None:
        self.sent: list[str] = []

    def publish(self, msg) -> None:
        self.sent.append(msg.data)


class _Node:
    """What LoopPerformance asks of controller_node: publishers (here: lists)."""

    def __init__(self) -> None:
        self.publishers: list[_Publisher] = []

    def create_publisher(self, *args, **kwargs) -> _Publisher:
        self.publishers.append(_Publisher())
        return self.publishers[-1]


def replayed(name: str) -> tuple[dict, Trace, list[dict]]:
    """The case run in-process, and the summaries controller_node's monitor publishes when fed
    its samples (plant time, y, r and the output at each controller sample)."""
    from tank_control.nodes.loop_performance import LoopPerformance
    sections = scenario.sections_of(SCENARIOS / f'monitor_{name}.yaml')
    trace = scenario.run_in_process(sections)
    values = dict(sections['controller'])
    setup = scenario.controller_setup(values, given=())
    node = _Node()
    monitor = LoopPerformance(node, values, setup.kind, float(values['sample_time']),
                              tuple(values['output_names']), tuple(values['input_names']))
    step = int(round(values['sample_time'] / sections['plant']['sample_time']))
    for k in range(0, len(trace), step):
        monitor.sample(int(round(trace.t[k] * 1e9)), np.array([trace['y.y'][k]]),
                       np.array([trace['r.y'][k]]), np.array([trace['u.u'][k]]), False, '')
    summaries = [json.loads(text) for text in node.publishers[0].sent]
    return sections, trace, summaries


def check_live(name: str, sections: dict, trace: Trace, last: dict) -> None:
    """The last summary of a run: the documented verdict, its dead time and the mode times."""
    duration = sections['harness']['duration']
    assert last['output'] == 'y' and last['time'] >= duration - 10.0, last['time']
    assert last['verdict'].startswith(LIVE[name]), last['verdict']
    # the dead time the controller knows of its process: tuning.dead_time of the file
    ts, dead_time = sections['controller']['sample_time'], sections['controller']['tuning.dead_time']
    assert last['dead_time'] == dead_time and 'tuning.*' in last['dead_time_source']
    assert last['dead_time_samples'] == math.floor(dead_time / ts + 1e-9) + 1
    assert last['manual_pct'] == 0.0 and last['fail_safe_pct'] == 0.0
    if name == 'saturated':
        # the time at a limit over the window, counted here from the trace
        window = (trace.t > last['time'] - 600.0) & (trace.t <= last['time'])
        u = trace['u.u'][window][::int(round(ts / sections['plant']['sample_time']))]
        at_limit = 100.0 * float(np.mean(np.abs(u) >= 50.0 - 1e-6))
        assert last['saturation_pct'] == pytest.approx(at_limit, abs=1.0)
        assert last['verdict'] == f'saturated {last["saturation_pct"]:.0f} % of the time'


@pytest.mark.parametrize('name', sorted(LIVE))
def test_live_verdict_of_each_shipped_case(name: str) -> None:
    sections, trace, summaries = replayed(name)
    assert not any(k.startswith('monitor.') for k in sections['controller'])   # defaults
    assert summaries
    check_live(name, sections, trace, summaries[-1])


@pytest.mark.parametrize('name', OVER_ROS)
def test_live_verdict_over_ros_is_the_replayed_one(tmp_path: Path, ros_env, name: str) -> None:
    path = SCENARIOS / f'monitor_{name}.yaml'
    result = run(path, tmp_path / 'ros', env=ros_env, plots=False)
    assert result.metrics['complete'], result.metrics['reason']
    sections, trace, summaries = replayed(name)
    ros = Trace.read_csv(tmp_path / 'ros' / 'trace.csv')
    assert len(ros) == len(trace)
    for column in trace.columns:
        np.testing.assert_allclose(ros.columns[column], trace.columns[column], rtol=0,
                                   atol=1e-9, err_msg=column)
    recorded = read_mcap(tmp_path / 'ros' / 'run.mcap')
    reports = [json.loads(m.data) for m in recorded.get('/controller/loop_performance', [])]
    assert reports, sorted(recorded)
    # the report of the replay's last instant (the nodes go on a few ticks after the run's
    # end, until the harness has stopped them: later reports are not the run's)
    last = next(r for r in reports if r['time'] == summaries[-1]['time'])
    check_live(name, sections, ros, last)
    assert last.keys() == summaries[-1].keys()
    for key, value in summaries[-1].items():
        if isinstance(value, float):
            assert last[key] == pytest.approx(value, rel=1e-6, abs=1e-9), key
        elif key != 'verdict':
            assert last[key] == value, key
    assert last['verdict'].split('(')[0] == summaries[-1]['verdict'].split('(')[0]
    if name == 'sticky_valve':
        # plant_node applies the actuator faults: the limit cycle (OP ramps over more than
        # S − J, PV swings) is in the ROS trace, equal to the in-process one above
        later = ros.t > 120
        assert np.ptp(ros['u.u'][later]) > 3.0 and np.ptp(ros['y.y'][later]) > 2.0
        # metrics.json carries the run's loop_performance, the in-process run's
        ref = run(path, tmp_path / 'ref', in_process=True, plots=False)
        assert result.metrics['loop_performance']['y'] == ref.metrics['loop_performance']['y']
        assert result.metrics['loop_performance']['y']['samples'] == len(ros)
