"""The loop monitor's dead time (core/monitoring/dead_time.py, docs/monitoring.md): from
monitor.dead_time, else from what the controller knows of its process — its tuning.* model, the
model a relay test identified, a multi-loop kind's own model per loop — else no Harris index,
with the reason; in runs the plant's model first. Never a one-sample guess shown as an index."""
from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from tank_control.core import scenario
from tank_control.core.monitoring import indices as ix
from tank_control.core.monitoring.dead_time import controller_dead_times
from tank_control.core.scenario import controller_setup
from tank_control.harness.performance import trace_performance

REPO = Path(__file__).resolve().parents[2]
PID = {'controller': 'pid', 'sample_time': 0.5, 'kp': 2.0, 'ti': 10.0}


def dead_times(values: dict) -> dict:
    setup = controller_setup(values, given=())
    outputs = list(setup.settings.channels.output_names)
    return controller_dead_times(setup.kind, setup.settings, outputs)


def test_a_pid_takes_its_tuning_model_dead_time_and_says_so() -> None:
    found = dead_times({**PID, 'tuning.gain': 1.5, 'tuning.time_constant': 20.0,
                        'tuning.dead_time': 3.0})['y']
    assert found.seconds == 3.0
    assert "controller's tuning.* model" in found.source and 'L=3 s' in found.source


def test_a_pid_without_a_model_has_no_dead_time_and_says_what_to_set() -> None:
    found = dead_times(PID)['y']
    assert found.seconds is None
    assert 'monitor.dead_time' in found.source and 'tuning.dead_time' in found.source


def test_the_model_a_relay_test_identified_gives_the_dead_time() -> None:
    before = dead_times({'controller': 'relay_autotune', 'sample_time': 0.5})['y']
    assert before.seconds is None
    after = dead_times({'controller': 'relay_autotune', 'sample_time': 0.5,
                        'autotune.model_kind': 'fopdt', 'autotune.model_gain': 0.8,
                        'autotune.model_time_constant': 12.0,
                        'autotune.model_dead_time': 2.5})['y']
    assert after.seconds == 2.5 and "controller's identified model" in after.source


def test_mpcs_answers_per_loop_from_its_prediction_model() -> None:
    sections = scenario.sections_of(REPO / 'config' / 'scenarios' / 'tank_mpcs_qp.yaml')
    values = scenario.node_values(sections, 'controller')
    found = dead_times(values)
    op = controller_setup(values, given=()).settings.config.operating_point()
    assert found['h'].seconds == 0.0                       # F_H reaches h undelayed
    assert found['T_out'].seconds == pytest.approx(op.tau_c + op.tau)   # F_Cin → T_out
    assert 'prediction model' in found['T_out'].source


def test_live_monitor_follows_the_controllers_current_values() -> None:
    """nodes/loop_performance.py asks at each assessment: a model identified while running
    (a relay test's results written to the parameters) is taken up."""
    from tank_control.nodes.loop_performance import LoopPerformance
    from tank_control.core.control.kinds import registry
    node = SimpleNamespace(create_publisher=lambda *a, **k: SimpleNamespace(publish=lambda m: 0))
    values = {'controller': 'relay_autotune', 'sample_time': 1.0, 'monitor.period': 100.0,
              'monitor.settle_time': 0.0}
    perf = LoopPerformance(node, lambda: values, registry.get_kind('relay_autotune'), 1.0,
                           ['y'], ['u'])
    rng = np.random.default_rng(0)
    for k in range(300):
        perf.sample(k * 10**9, np.array([rng.standard_normal()]), np.zeros(1), np.zeros(1),
                    False, '')
    first = perf.monitors['y'][1].summary()
    assert first['harris_index'] is None and 'monitor.dead_time' in first['harris_reason']
    assert 'dead time not known' in perf.fields()['monitor.dead_time_source.y']
    values.update({'autotune.model_kind': 'fopdt', 'autotune.model_gain': 1.0,
                   'autotune.model_time_constant': 10.0, 'autotune.model_dead_time': 3.0})
    for k in range(300, 400):
        perf.sample(k * 10**9, np.array([rng.standard_normal()]), np.zeros(1), np.zeros(1),
                    False, '')
    second = perf.monitors['y'][1].summary()
    assert second['dead_time_samples'] == 4 and second['harris_index'] is not None
    assert perf.fields()['monitor.dead_time_source.y'].startswith(
        "3 s from controller's identified model")


def test_a_noise_free_error_gets_no_harris_index() -> None:
    """A deterministic error (a noise-free simulation) is predictable a sample ahead: index
    would be ~0 at any dead time; none is given (innovation variance below 1e-5 of it)."""
    t = np.arange(4000)
    e = np.exp(-t / 300.0) * np.sin(t / 40.0)
    assert ix.harris_index(e, b=1) is None
    noisy = e + 0.01 * np.random.default_rng(1).standard_normal(t.size)
    assert ix.harris_index(noisy, b=1) is not None


def test_the_tanks_loops_get_no_misleading_harris_index_in_a_run() -> None:
    """tank_mpcs_qp (no measurement noise): no index of 0.00 and no "retune" verdict for it;
    the reason and the dead time's source are in the body."""
    sections = scenario.sections_of(REPO / 'config' / 'scenarios' / 'tank_mpcs_qp.yaml')
    sections['harness'] = {**sections.get('harness', {}), 'duration': 400.0}
    body = trace_performance(scenario.run_in_process(sections), sections)
    for y in ('h', 'T_out'):
        assert body[y]['harris_index'] is None and body[y]['harris_reason'], body[y]
        assert not body[y]['verdict'].startswith('retune (sluggish'), body[y]['verdict']
        assert 'prediction model' in body[y]['dead_time_source']
    sections = scenario.sections_of(REPO / 'config' / 'tank_two_loop.yaml')
    sections['harness'] = {**sections.get('harness', {}), 'duration': 400.0}
    body = trace_performance(scenario.run_in_process(sections), sections)
    assert body['h']['harris_index'] is None
    assert 'monitor.dead_time' in body['h']['dead_time_source']


def test_a_run_prefers_the_plants_model() -> None:
    sections = scenario.sections_of(REPO / 'config' / 'scenarios' / 'monitor_well_tuned.yaml')
    sections['controller'] = {**sections['controller'], 'tuning.dead_time': 7.0}
    sections['harness'] = {**sections['harness'], 'duration': 400.0}
    body = trace_performance(scenario.run_in_process(sections), sections)['y']
    assert body['dead_time'] == 2.0 and body['dead_time_source'].startswith("plant's model")
    sections['controller']['monitor.dead_time'] = 4.0
    body = trace_performance(scenario.run_in_process(sections), sections)['y']
    assert body['dead_time'] == 4.0 and body['dead_time_source'] == 'monitor.dead_time'
