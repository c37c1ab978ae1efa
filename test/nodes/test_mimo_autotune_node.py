"""controller: two_loop_pi with its multivariable auto-tuning (004 §3.7) in controller_node: the
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
