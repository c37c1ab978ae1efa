"""controller: two_loop_pi with its multivariable auto-tuning ([Precup2013] §3.7) in controller_node: the
operator commands ``~/start_autotune``, ``~/apply_autotune``, ``~/revert_gains``,
``~/abort_autotune`` as std_srvs/Trigger services, the state on ``~/autotune_state`` and the
results and running gains in parameters (the same interface as relay_autotune). The lockstep
trace equal to the in-process loop: test/harness/test_mimo_autotune_scenarios.py."""
from __future__ import annotations

import pytest
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from std_msgs.msg import String
from std_srvs.srv import Trigger
from support import SCENARIOS

from tank_control.core import params_file
from tank_control.core.control.mimo_autotune import MimoAutotuneConfig, model_design
from tank_control.core.control.multiloop import document_config
from tank_control.nodes.controller_node import STATE_QOS

GAINS = ('two_loop.kp_h', 'two_loop.ki_h', 'two_loop.kp_T', 'two_loop.ki_T')


def _msg(name, value):
    from rcl_interfaces.msg import Parameter as ParameterMsg
    return ParameterMsg(name=name, value=value)


def test_model_ls_preview_apply_revert_over_services(procs, ros_env, node_cmd, probe, tmp_path):
    params = params_file.read(SCENARIOS / 'tank_pi_autotuned.yaml')
    params['controller'].update({'autotune.mode': 'model_ls', 'autotune.apply': 'preview',
                                 'autotune.start_time': 0.0})
    path = params_file.write({'controller': params['controller']}, tmp_path / 'mimo.yaml')
    node = probe.node
    states: list[str] = []
    sub = node.create_subscription(String, '/controller/autotune_state',
                                   lambda m: states.append(m.data), STATE_QOS)
    procs.start('controller', node_cmd('controller_node', '--params-file', str(path)),
                env=ros_env)
    client = AsyncParameterClient(node, 'controller')
    services = {name: node.create_client(Trigger, f'/controller/{name}')
                for name in ('start_autotune', 'apply_autotune', 'revert_gains',
                             'abort_autotune')}
    assert probe.wait_for(lambda: sub.get_publisher_count() and client.services_are_ready()
                          and all(s.service_is_ready() for s in services.values()), 30), \
        procs.processes['controller'].tail()

    def result(future):
        assert probe.wait_for(future.done, 10)
        return future.result()

    def trigger(name):
        return result(services[name].call_async(Trigger.Request()))

    def get(*names):
        values = result(client.get_parameters(list(names))).values
        return {n: Parameter.from_parameter_msg(_msg(n, v)).value for n, v in zip(names, values)}

    assert probe.wait_for(lambda: states[-1:] == ['idle'], 20), states
    file_gains = get(*GAINS)
    assert trigger('abort_autotune').success is False               # nothing runs
    reply = trigger('start_autotune')
    assert reply.success and 'model_ls designed (proposed)' in reply.message
    assert probe.wait_for(lambda: states[-1:] == ['proposed'], 20), states
    got = get(*GAINS, 'autotune.proposed_kp_h', 'autotune.proposed_ki_T', 'autotune.ls_residual')
    assert [got[k] for k in GAINS] == [file_gains[k] for k in GAINS]    # preview: not applied
    cfg = document_config('dynamic', kp_h=0.04, ki_h=0.0004, kp_T=0.0, ki_T=-0.01)
    loops, found = model_design(cfg, MimoAutotuneConfig(mode='model_ls'))
    assert got['autotune.proposed_kp_h'] == pytest.approx(loops[0].kp, rel=1e-12)
    assert got['autotune.proposed_ki_T'] == pytest.approx(loops[1].ki, rel=1e-12)
    assert got['autotune.ls_residual'] == pytest.approx(found['ls_residual'], rel=1e-12)

    assert trigger('apply_autotune').success
    assert probe.wait_for(lambda: states[-1:] == ['running'], 20), states
    applied = get(*GAINS)
    assert applied['two_loop.kp_h'] == pytest.approx(loops[0].kp, rel=1e-12)
    assert applied['two_loop.ki_T'] == pytest.approx(loops[1].ki, rel=1e-12)

    assert trigger('revert_gains').success
    assert probe.wait_for(lambda: states[-1:] == ['reverted'], 20), states
    assert get(*GAINS) == file_gains
    assert states == ['idle', 'proposed', 'running', 'reverted']
    # result parameters are read-only for users
    refused = result(client.set_parameters([Parameter('autotune.ku_h', value=1.0)]))
    assert not refused.results[0].successful


def test_relay_test_abort_and_failure_restore_the_gains_over_the_graph(procs, ros_env, node_cmd,
                                                                       probe, tmp_path):
    """tank_pi_autotuned's sequential relay test on the running graph (plant, controller,
    reference; lockstep at 200x real time), started by the service: the relay runs on loop h
    (stage 1); ``~/abort_autotune`` ends it with [Michalski2021]'s gains back; started again by the
    ``autotune.start`` parameter with a 50 s relay timeout it fails, gains back again."""
    params = params_file.read(SCENARIOS / 'tank_pi_autotuned.yaml')
    params['controller']['autotune.start_time'] = 0.0
    for name in ('plant', 'controller', 'reference'):   # the file's harness section says it
        params[name]['clock_mode'] = 'lockstep'
    # paced at 200x real time, not as fast as possible: the relay on loop h lasts thousands of
    # seconds, so it is still running when the abort comes even if this process is starved a while
    params['plant']['real_time_factor'] = 200.0
    path = params_file.write({n: params[n] for n in ('plant', 'controller', 'reference')},
                             tmp_path / 'relay.yaml')
    node = probe.node
    states: list[str] = []
    sub = node.create_subscription(String, '/controller/autotune_state',
                                   lambda m: states.append(m.data), STATE_QOS)
    for name in ('plant', 'controller', 'reference'):
        procs.start(name, node_cmd(f'{name}_node', '--params-file', str(path)), env=ros_env)
    client = AsyncParameterClient(node, 'controller')
    start = node.create_client(Trigger, '/controller/start_autotune')
    abort = node.create_client(Trigger, '/controller/abort_autotune')
    logs = lambda: '\n'.join(p.tail() for p in procs.processes.values())   # noqa: E731
    assert probe.wait_for(lambda: sub.get_publisher_count() and client.services_are_ready()
                          and start.service_is_ready() and abort.service_is_ready(), 30), logs()

    def result(future):
        assert probe.wait_for(future.done, 10)
        return future.result()

    def get(*names):
        values = result(client.get_parameters(list(names))).values
        return {n: Parameter.from_parameter_msg(_msg(n, v)).value for n, v in zip(names, values)}

    def wait_state(state, since=0, timeout=120.0):
        assert probe.wait_for(lambda: state in states[since:], timeout), (states, logs())

    wait_state('idle', timeout=30)
    file_gains = get(*GAINS)
    assert result(start.call_async(Trigger.Request())).success
    wait_state('relay')
    got = get('autotune.relay_loop', 'autotune.relay_stage')
    assert got == {'autotune.relay_loop': 'h', 'autotune.relay_stage': 1}
    reply = result(abort.call_async(Trigger.Request()))
    assert reply.success and 'restored' in reply.message
    wait_state('aborted')
    got = get('autotune.state', 'autotune.reason', *GAINS)
    assert got == {'autotune.state': 'aborted', 'autotune.reason': 'abort requested',
                   **file_gains}

    since = len(states)
    params_set = [Parameter('autotune.timeout', value=50.0),
                  Parameter('autotune.start', value=True)]
    assert all(r.successful for r in result(client.set_parameters(params_set)).results)
    wait_state('failed', since=since)
    got = get('autotune.state', 'autotune.reason', 'autotune.start', *GAINS)
    assert 'no oscillation within autotune.timeout = 50 s' in got['autotune.reason']
    assert got['autotune.start'] is False
    assert {k: got[k] for k in GAINS} == file_gains
