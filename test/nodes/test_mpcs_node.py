"""controller: mpcs in controller_node over real DDS: plant (mixing_tank, lockstep as
fast as possible), controller (MPCS, QP) and reference in three processes.

* The recorded lockstep run equals ``core/loop.py`` in-process to 1e-9 on every signal,
  including a runtime ``mpcs.horizon`` change: the plant is paused (``lockstep.paused``) so
  the tick at which the change takes effect is known, ``mpcs.horizon`` is set to 300, the
  loop resumes; in-process the same change is applied at that tick through the registry
  (``step_with_changes``, as the node does).
* 300 samples are shorter than the F_Cin dead time plus the model's settling: the change
  is accepted, and the controller's warning is logged and shown in ``/diagnostics``
  (level WARN, ``status.warning``, ``status.warnings``); the file's defaults give none.
* The reference publishes F_D but not T_D: the node passes T_D as NaN and MPCS uses its
  operating point (33 °C), the plant its nominal T_D (33 °C) — the same values in-process.
* Invalid changes (``mpcs.horizon 0``, ``mpcs.solver foo``, ``mpcs.control_horizon`` above the
  horizon) are refused with the reason while the loop keeps running.
* In wall mode a horizon change (built in a worker thread, nodes/live_rebuild.py, and switched
  at the first sample after it is ready) misses no sample.
"""
from __future__ import annotations


import numpy as np
import pytest
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from sensor_msgs.msg import JointState
from support import SCENARIOS
from support.gated_recorder import GATE_REMAP, gated_recorder
from support.held import HELD_TOPICS, per_tick

from tank_control.core import params_file
from tank_control.core.control.kinds import registry
from tank_control.core.control.kinds.base import resolve
from tank_control.core.loop import run_loop
from tank_control.core.scenario import build
from tank_control.harness.trace import GATED_DISTURBANCE
from tank_control.nodes.messages import ORIGIN_QOS, from_joint_state, ns_to_stamp, to_joint_state

NODES = ('plant', 'controller', 'reference')
TOPICS = {'measurement': 'y', 'setpoint': 'r', 'manipulated': 'u', 'disturbance': 'd'}
TS_NS = 1_000_000_000


def short_params() -> dict:
    """config/scenarios/tank_mpcs_qp.yaml, shortened to a few hundred ticks, with noise."""
    params = params_file.read(SCENARIOS / 'tank_mpcs_qp.yaml')
    params['plant'].update({'noise_std': [0.02, 0.01], 'seed': 3, 'lockstep.paused': True,
                            'real_time_factor': 0.0, 'diagnostics_period': 0.1})
    ref = params['reference']
    ref.update({'setpoint.h.times': [0.0, 5.0], 'setpoint.h.values': [81.0, 83.0],
                'setpoint.T_out.times': [0.0, 20.0], 'setpoint.T_out.values': [33.5, 34.5],
                'disturbance.channels': ['F_D'],          # T_D not published
                'disturbance.F_D.times': [0.0, 60.0], 'disturbance.F_D.values': [12.0, 15.0]})
    del ref['disturbance.T_D.value']
    return params


def test_mpcs_lockstep_equals_in_process_with_a_runtime_horizon_change(procs, ros_env, node_cmd,
                                                                        probe, tmp_path):
    params = short_params()
    # the file's clock mode is the harness's; here every node is told lockstep directly
    path = params_file.write({'/**': {'clock_mode': 'lockstep'}, **{n: params[n] for n in NODES}},
                             tmp_path / 'mpcs.yaml')
    # every tick recorded, however slowly this process runs (test/support/gated_recorder.py)
    with gated_recorder('test_mpcs_recorder') as recorder:
        _run_with_horizon_change(procs, ros_env, node_cmd, probe, path, params, recorder)


def _run_with_horizon_change(procs, ros_env, node_cmd, probe, path, params, recorder):
    node = probe.node
    plant_diag: list[dict[str, str]] = []
    node.create_subscription(DiagnosticArray, '/diagnostics', lambda msg: plant_diag.extend(
        {kv.key: kv.value for kv in st.values} for st in msg.status if st.name == 'plant'), 50)
    ctrl_diag: list[tuple[int, str, dict[str, str]]] = []
    node.create_subscription(DiagnosticArray, '/diagnostics', lambda msg: ctrl_diag.extend(
        (int.from_bytes(st.level, 'little') if isinstance(st.level, bytes) else int(st.level),
         st.message, {kv.key: kv.value for kv in st.values})
        for st in msg.status if st.name.startswith('controller')), 50)
    for name in NODES:
        argv = node_cmd(f'{name}_node', '--params-file', str(path))
        if name == 'plant':
            argv += GATE_REMAP                                       # through the recorder
        procs.start(name, argv, env=ros_env)

    def logs() -> str:
        return '\n'.join(p.tail() for p in procs.processes.values())
    assert probe.wait_for(lambda: all(recorder.publisher_count(t) for t in TOPICS)
                          and recorder.subscriber_count(GATED_DISTURBANCE), 30), logs()
    controller = AsyncParameterClient(node, 'controller')
    plant = AsyncParameterClient(node, 'plant')
    assert probe.wait_for(lambda: controller.services_are_ready()
                          and plant.services_are_ready(), 20), logs()

    def call(future):
        assert probe.wait_for(future.done, 10), logs()
        return future.result()

    def set_params(client, **values):
        return call(client.set_parameters([Parameter(k, value=v) for k, v in values.items()]))

    # the mpcs.* parameters are declared with descriptors (ranges from mpcs_params())
    desc = call(controller.describe_parameters(['mpcs.horizon', 'mpcs.solver'])).descriptors
    assert 'prediction horizon' in desc[0].description
    assert (desc[0].integer_range[0].from_value, desc[0].integer_range[0].to_value) == (1, 2000)
    assert 'analytic' in desc[1].description

    def last(topic: str) -> int:
        return recorder.latest.get(topic, -1)

    # run to tick >= 100, pause, let the answers of the last published tick arrive
    assert set_params(plant, **{'lockstep.paused': False}).results[0].successful
    assert probe.wait_for(lambda: last('manipulated') >= 100 * TS_NS, 60), logs()
    assert set_params(plant, **{'lockstep.paused': True}).results[0].successful
    # paused = the plant waits for no answer (its diagnostics have no waiting_for); its
    # sim_time is then the next tick, the first one computed with the change
    plant_diag.clear()
    assert probe.wait_for(lambda: any('waiting_for' not in d for d in plant_diag), 10), logs()
    k_change = round(float(next(d for d in plant_diag if 'waiting_for' not in d)['sim_time']))
    assert probe.wait_for(lambda: last('manipulated') == (k_change - 1) * TS_NS, 10), logs()
    # the file's horizons (the defaults) give no warning
    assert probe.wait_for(lambda: ctrl_diag, 10), logs()
    # (a WARN of the loop monitor's own verdict, docs/monitoring.md, is not the MPCS's)
    level, message, fields = ctrl_diag[-1]
    assert fields['status.warning'] == '' and 'warning' not in message, message
    assert level == 0 or any(k.startswith('loop_performance.') for k in fields), message
    result = set_params(controller, **{'mpcs.horizon': 300}).results[0]
    assert result.successful, result.reason
    assert set_params(plant, **{'lockstep.paused': False}).results[0].successful
    # applied at the next sample: the warning is logged and shown in /diagnostics
    assert probe.wait_for(lambda: any(d[2]['status.warning'].startswith('mpcs.horizon: 300 ')
                                      for d in ctrl_diag), 30), logs()
    level, message, fields = next(d for d in ctrl_diag if d[2]['status.warning'])
    assert level == 1 and 'warning: mpcs.horizon: 300 ' in message   # DiagnosticStatus.WARN
    assert 'at least 472' in fields['status.warning'] and fields['status.warnings'] == '1'
    assert probe.wait_for(lambda: 'mpcs.horizon: 300 samples' in procs.processes[
        'controller'].tail(200), 10), logs()

    # invalid changes while running: refused with the parameter and the allowed range/choices
    refused = {}
    for name, value in (('mpcs.horizon', 0), ('mpcs.solver', 'foo'),
                        ('mpcs.control_horizon', 301)):
        res = set_params(controller, **{name: value}).results[0]
        assert not res.successful
        refused[name] = res.reason
    assert 'mpcs.horizon' in refused['mpcs.horizon'] and '1' in refused['mpcs.horizon']
    assert 'mpcs.solver' in refused['mpcs.solver'] and 'analytic' in refused['mpcs.solver']
    assert 'mpcs.control_horizon' in refused['mpcs.control_horizon'] \
        and '300' in refused['mpcs.control_horizon']
    values = call(controller.get_parameters(['mpcs.horizon', 'mpcs.solver'])).values
    assert (values[0].integer_value, values[1].string_value) == (300, 'qp')

    last_tick = k_change + 150                            # the loop continued
    assert probe.wait_for(lambda: all(last(t) >= last_tick * TS_NS for t in TOPICS), 60), logs()

    # in-process: the same objects; the change applied at k_change as the node applies it
    built = build(params)
    kind = built.controller_setup.kind
    changed = resolve(kind, {**built.controller_setup.settings.values, 'mpcs.horizon': 300},
                      given=())
    inner = built.controller

    class AtTick:
        output_names, input_names = inner.output_names, inner.input_names
        disturbance_names, sample_time = inner.disturbance_names, inner.sample_time

        def step(self, t, y, r, d):
            if round(t) == k_change:
                _, u = registry.step_with_changes(kind, inner, changed,
                                                  frozenset({'mpcs.horizon'}), t, y, r, d)
                return u
            return inner.step(t, y, r, d)
    trace = run_loop(built.plant, AtTick(), built.reference, sample_time=built.sample_time,
                     duration=float(last_tick), noise=built.noise.sample)
    assert inner.config.horizon == 300

    seen: dict[str, dict[int, tuple]] = {topic: {} for topic in TOPICS}
    for m in recorder.signal_messages():
        assert seen[m.topic].setdefault(m.stamp_ns, (m.names, m.values)) == (m.names, m.values)
    for topic in HELD_TOPICS:          # the reference's: once per change, zero-order hold
        seen[topic] = per_tick(seen[topic], [k * TS_NS for k in range(last_tick + 1)])
    worst: dict[str, float] = {}
    for topic, prefix in TOPICS.items():
        assert all(k * TS_NS in seen[topic] for k in range(last_tick + 1)), topic   # the gate
        names = seen[topic][0][0]
        for i, name in enumerate(names):
            ros = np.array([seen[topic][k * TS_NS][1][i] for k in range(last_tick + 1)])
            worst[f'{prefix}.{name}'] = float(np.max(np.abs(ros - trace[f'{prefix}.{name}'])))
    assert set(worst) == set(trace.names) - {'t'}
    assert max(worst.values()) <= 1e-9, worst
    # not trivial: both flows moved, the F_D step is in, no NaN ever left the controller
    assert np.ptp(trace['u.F_H']) > 0.5 and np.ptp(trace['u.F_Cin']) > 0.5
    assert trace['d.F_D'][-1] == 15.0 and np.all(np.isfinite(trace['u.F_H']))


@pytest.mark.parametrize('trigger', ['measurement', 'timer'])
def test_wall_mode_horizon_change_rebuilds_without_missing_a_sample(procs, ros_env, node_cmd,
                                                                    probe, trigger):
    """wall clock, Ts = 1 s: ``mpcs.horizon`` 600 → 300 is built in the worker thread and
    switched at a sample (the measurement's or the timer's; docs/mpcs.md); the samples around
    it stay 1 s apart and finite."""
    argv = node_cmd('controller_node', *[x for p in (
        'controller:=mpcs', 'clock_mode:=wall', 'mpcs.solver:=qp', 'diagnostics_period:=0.2',
        f'trigger:={trigger}') for x in ('-p', p)])
    procs.start('controller', argv, env=ros_env)
    node = probe.node
    meas = node.create_publisher(JointState, 'measurement', 10)
    setp = node.create_publisher(JointState, 'setpoint', 10)
    answers: list[tuple[int, list[float]]] = []
    diag: dict[str, str] = {}
    node.create_subscription(JointState, 'manipulated', lambda m: answers.append(
        (from_joint_state(m)[0], list(m.position))), 10)
    node.create_subscription(DiagnosticArray, '/diagnostics', lambda msg: diag.update(
        {kv.key: kv.value for st in msg.status if st.name.startswith('controller')
         for kv in st.values}), 10)

    def feed():
        now = node.get_clock().now().nanoseconds
        meas.publish(to_joint_state(now, ['h', 'T_out'], [81.0, 2115.0 / 63.0]))
        setp.publish(to_joint_state(now, ['h', 'T_out'], [82.0, 34.0]))
    node.create_timer(0.05, feed)
    # the probe is the plant: its time origin (latched), the controller's loop time base
    node.create_publisher(Time, 'time_origin', ORIGIN_QOS).publish(
        ns_to_stamp(node.get_clock().now().nanoseconds))
    controller = AsyncParameterClient(node, 'controller')
    assert probe.wait_for(lambda: len(answers) >= 2, 30), \
        '\n'.join(p.tail() for p in procs.processes.values())
    future = controller.set_parameters([Parameter('mpcs.horizon', value=300)])
    assert probe.wait_for(future.done, 10) and future.result().results[0].successful
    n = len(answers)
    assert probe.wait_for(lambda: len(answers) >= n + 3, 10)
    assert probe.wait_for(lambda: diag.get('status.horizon') == '300', 5), diag
    gaps = np.diff([a[0] for a in answers]) / 1e9
    if trigger == 'measurement':
        # its first sample is the first measurement after the origin came, anywhere in a
        # period of the grid (the probe's stamps are its wall time, not a plant's ticks)
        gaps = gaps[1:]
    assert np.all((gaps > 0.7) & (gaps < 1.3)), gaps          # no sample missed or doubled
    assert all(np.all(np.isfinite(a[1])) for a in answers)
