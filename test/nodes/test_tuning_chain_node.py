"""The tuning chain and the live robustness guard over real DDS: plant, controller and reference
as three processes in lockstep (as fast as possible), operated as a user does — parameter
sets (what ``ros2 param set`` sends), ``std_srvs/Trigger`` services, ``/diagnostics``.

* controller: pid on [DeadTimeNotes]'s FOPDT with the model in tuning.*: the running loop's robustness.*
  and a gain change refused by robustness.ms_max with the numbers in the reason, also
  through the project's ``ros2 param set`` (exit 1, the reason printed);
* controller: relay_autotune (config/fopdt_ms_autotune.yaml): relay test → proposal (preview)
  → a rule change re-derives it from the stored model → ~/apply_autotune → verification
  step → ~/revert_gains, equal numbers to the core objects'.
"""
from __future__ import annotations

from pathlib import Path

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import Parameter as ParameterMsg
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from std_msgs.msg import String
from std_srvs.srv import Trigger
from support import CONFIG
from support.ros2cli import ros2

from tank_control.core import params_file
from tank_control.core.analysis.robustness import loop_report
from tank_control.core.control.pid import PidConfig
from tank_control.core.tuning.model import ProcessModel
from tank_control.core.tuning.rules import tune
from tank_control.nodes.controller_node import STATE_QOS

NODES = ('plant', 'controller', 'reference')


class Operator:
    """The three nodes from ``params``, and the probe as the operator: parameters, services,
    the state topic and /diagnostics."""

    def __init__(self, procs, ros_env, node_cmd, probe, tmp_path: Path, params: dict,
                 services: tuple[str, ...] = ()) -> None:
        path = params_file.write(params, tmp_path / 'chain.yaml')
        self.probe, self.procs = probe, procs
        node = probe.node
        self.states: list[str] = []
        self.diag: dict[str, str] = {}
        self.diag_level = 0
        self.diag_message = ''
        self.sub = node.create_subscription(String, '/controller/autotune_state',
                                            lambda m: self.states.append(m.data), STATE_QOS)
        node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, 10)
        for name in NODES:
            procs.start(name, node_cmd(f'{name}_node', '--params-file', str(path)), env=ros_env)
        self.controller = AsyncParameterClient(node, 'controller')
        self.plant = AsyncParameterClient(node, 'plant')
        self.services = {name: node.create_client(Trigger, f'/controller/{name}')
                         for name in services}
        assert probe.wait_for(lambda: self.controller.services_are_ready()
                              and self.plant.services_are_ready()
                              and all(c.service_is_ready() for c in self.services.values()),
                              40), self.logs()

    def _on_diag(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.startswith('controller:'):
                self.diag = {kv.key: kv.value for kv in status.values}
                self.diag_message = status.message
                self.diag_level = int.from_bytes(status.level, 'little') \
                    if isinstance(status.level, bytes) else int(status.level)

    def logs(self) -> str:
        return '\n'.join(p.tail() for p in self.procs.processes.values())

    def result(self, future, timeout: float = 20.0):
        assert self.probe.wait_for(future.done, timeout), self.logs()
        return future.result()

    def get(self, *names: str) -> dict:
        values = self.result(self.controller.get_parameters(list(names))).values
        return {n: Parameter.from_parameter_msg(ParameterMsg(name=n, value=v)).value
                for n, v in zip(names, values)}

    def set(self, client, **values):
        """Set parameters (``a__b`` is ``a.b``); returns the SetParametersResult list."""
        params = [Parameter(n.replace('__', '.'), value=v) for n, v in values.items()]
        return self.result(client.set_parameters(params)).results

    def call(self, service: str) -> Trigger.Response:
        return self.result(self.services[service].call_async(Trigger.Request()))

    def wait_param(self, name: str, predicate, timeout: float = 60.0):
        seen = {}

        def ok() -> bool:
            seen['v'] = self.get(name)[name]
            return predicate(seen['v'])
        assert self.probe.wait_for(ok, timeout), (name, seen, self.logs())
        return seen['v']

    def wait_state(self, state: str, timeout: float = 90.0) -> None:
        assert self.probe.wait_for(lambda: state in self.states, timeout), (self.states,
                                                                          self.logs())


ZN = dict(kp=70.92, ti=5.5, td=1.32)
MODEL = ProcessModel('fopdt', 0.05, 3.0, 10.0)


def test_live_robustness_and_guard_of_a_pid(procs, ros_env, node_cmd, probe, tmp_path):
    params = params_file.read(CONFIG / 'fopdt_zn.yaml')
    params.pop('harness')
    params['controller'].update({'tuning.gain': 0.05, 'tuning.time_constant': 10.0,
                                 'tuning.dead_time': 3.0, 'robustness.ms_max': 3.0})
    op = Operator(procs, ros_env, node_cmd, probe, tmp_path, params)
    zn = loop_report(MODEL, PidConfig(sample_time=0.1, **ZN))
    ms = op.wait_param('robustness.ms', lambda v: v > 0)          # after the first sample
    assert ms == pytest.approx(zn.ms, rel=1e-9)
    got = op.get('robustness.model', 'robustness.stable', 'robustness.gain_margin',
                 'robustness.phase_margin', 'robustness.delay_margin', 'robustness.crossover')
    assert got['robustness.model'] == 'fopdt K=0.05 T=10 s L=3 s' and got['robustness.stable']
    assert got['robustness.gain_margin'] == pytest.approx(zn.gain_margin, rel=1e-9)
    assert got['robustness.delay_margin'] == pytest.approx(zn.delay_margin, rel=1e-9)
    assert probe.wait_for(lambda: 'robustness.ms' in op.diag, 20), op.diag
    assert float(op.diag['robustness.ms']) == pytest.approx(zn.ms, rel=1e-9)

    # the rule sets the gains: to change kp by hand, rule none first
    assert all(r.successful for r in op.set(op.controller, tuning__rule='none'))
    worse = loop_report(MODEL, PidConfig(sample_time=0.1, **{**ZN, 'kp': 85.0}))
    refused = op.set(op.controller, kp=85.0)[0]
    assert not refused.successful
    assert refused.reason.startswith('kp: Ms would be ')
    assert f'Ms would be {worse.ms:.3g} > robustness.ms_max 3' in refused.reason
    assert op.get('kp')['kp'] == 70.92
    unstable = op.set(op.controller, kp=150.0)[0]
    assert not unstable.successful and 'kp: the loop would be unstable' in unstable.reason
    # the project's `ros2 param set` prints the reason and exits 1
    cli = ros2(ros_env, 'param', 'set', '/controller', 'robustness.ms_max', '2.0')
    assert cli.returncode == 1
    assert f'robustness.ms_max: Ms would be {zn.ms:.3g} > robustness.ms_max 2' in cli.stderr
    # an acceptable change is taken, and the analysis follows it
    assert all(r.successful for r in op.set(op.controller, kp=40.0))
    better = loop_report(MODEL, PidConfig(sample_time=0.1, **{**ZN, 'kp': 40.0}))
    assert op.wait_param('robustness.ms', lambda v: v != ms) == pytest.approx(better.ms,
                                                                               rel=1e-9)
    # a change of the model alone is never refused; it is reported (Ms above the bound)
    assert all(r.successful for r in op.set(op.controller, tuning__dead_time=5.5))
    slower = loop_report(ProcessModel('fopdt', 0.05, 5.5, 10.0),
                         PidConfig(sample_time=0.1, **{**ZN, 'kp': 40.0}))
    assert slower.ms > 3.0
    warning = op.wait_param('robustness.warning', bool)
    assert f'Ms {slower.ms:.3g} > robustness.ms_max 3' in warning
    assert probe.wait_for(lambda: op.diag_level == 1 and 'robustness.warning' in op.diag, 20)
    # [DeadTimeNotes]'s sampling advice follows the model: L = 0.3 s puts sample_time 0.1 s above 0.3·L
    assert op.get('sampling.warning')['sampling.warning'] == ''
    assert all(r.successful for r in op.set(op.controller, tuning__dead_time=0.3))
    advice = op.wait_param('sampling.warning', bool)
    assert advice.startswith('sample_time 0.1 s is above 0.3·L = 0.09 s'), advice
    assert probe.wait_for(lambda: 'sampling.warning: sample_time 0.1 s' in op.diag_message, 20)
    assert probe.wait_for(lambda: 'sampling.warning: sample_time 0.1 s' in op.logs(), 20)


def test_preview_rule_change_apply_verify_revert_over_dds(procs, ros_env, node_cmd, probe,
                                                          tmp_path):
    params = params_file.read(CONFIG / 'fopdt_ms_autotune.yaml')
    params.pop('harness')
    params['plant'].update({'real_time_factor': 0.0})
    params['controller'].update({'autotune.start_time': 0.0, 'autotune.apply_time': 0.0})
    op = Operator(procs, ros_env, node_cmd, probe, tmp_path, params,
                  services=('start_autotune', 'apply_autotune', 'revert_gains'))
    assert not op.call('apply_autotune').success             # nothing proposed yet
    assert op.call('start_autotune').success
    op.wait_state('proposed')
    got = op.get('kp', 'ti', 'td', 'autotune.proposed_kp', 'autotune.proposed_ti',
                 'autotune.proposed_td', 'autotune.proposed_ms', 'autotune.model_gain',
                 'autotune.model_time_constant', 'autotune.model_dead_time',
                 'autotune.predicted_overshoot', 'autotune.predicted_iae_load')
    assert (got['kp'], got['ti'], got['td']) == (20.0, 12.0, 0.0)    # preview: unchanged
    model = dict(gain=got['autotune.model_gain'], time_constant=got['autotune.model_time_constant'],
                 dead_time=got['autotune.model_dead_time'])
    design = tune('ms', 'pid', ms=1.4, sample_time=0.1, filter_n=10.0, **model)
    assert got['autotune.proposed_kp'] == pytest.approx(design['kp'], rel=1e-9)
    assert got['autotune.proposed_ms'] == pytest.approx(1.4, rel=1e-3)
    assert got['autotune.predicted_overshoot'] > 0 and got['autotune.predicted_iae_load'] > 0

    # a rule change re-derives the proposal from the stored model (no new test)
    since = len(op.states)
    assert all(r.successful for r in op.set(op.controller, autotune__rule='amigo'))
    amigo = tune('amigo', 'pid', **model)
    assert op.wait_param('autotune.proposed_kp', lambda v: v != got['autotune.proposed_kp']) \
        == pytest.approx(amigo['kp'], rel=1e-9)
    assert 'settling' not in op.states[since:]
    assert all(r.successful for r in op.set(op.controller, autotune__rule='ms'))
    op.wait_param('autotune.proposed_kp', lambda v: v == pytest.approx(design['kp'], rel=1e-9))

    reply = op.call('apply_autotune')
    assert reply.success and 'predicted Ms 1.4' in reply.message
    op.wait_state('running')
    assert op.wait_param('kp', lambda v: v != 20.0) == pytest.approx(design['kp'], rel=1e-9)
    # the verification step (5, from the file) measured against its prediction
    assert op.wait_param('autotune.verify_state', lambda v: v in ('ok', 'worse'), 120) == 'ok'
    check = op.get('autotune.verify_iae_measured', 'autotune.verify_iae_predicted',
                   'autotune.verify_step_size', 'robustness.ms')
    assert check['autotune.verify_step_size'] == 5.0
    assert check['autotune.verify_iae_measured'] == pytest.approx(
        check['autotune.verify_iae_predicted'], rel=0.10)
    assert check['robustness.ms'] == pytest.approx(1.4, rel=1e-3)
    assert probe.wait_for(lambda: 'autotune.proposed_ms' in op.diag, 20), op.diag
    assert float(op.diag['autotune.proposed_ms']) == pytest.approx(1.4, rel=1e-3)
    assert op.diag['autotune.verify_state'] == 'ok' or probe.wait_for(
        lambda: op.diag['autotune.verify_state'] == 'ok', 20)

    # a hand-set gain beyond robustness.ms_max (2) on the identified model is refused
    refused = op.set(op.controller, kp=3 * design['kp'])[0]
    assert not refused.successful and 'robustness.ms_max 2' in refused.reason

    reply = op.call('revert_gains')
    assert reply.success
    op.wait_state('reverted')
    assert op.wait_param('kp', lambda v: v == 20.0) == 20.0
    assert op.get('ti', 'td') == {'ti': 12.0, 'td': 0.0}
