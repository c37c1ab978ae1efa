"""An MPCS horizon change built off the sampling path (nodes/live_rebuild.py, as
controller_node does in wall mode): built from a copy taken when the change was accepted while
the running MPCS samples on, it switches at a later sample exactly as the change made at that
sample in-process (``registry.step_with_changes``): the same trace, bit for bit, so the switch
is as bumpless as a change on the sampling path (the input continues from its last value)."""
from __future__ import annotations

import copy

import numpy as np
from support import SCENARIOS

from tank_control.core import params_file
from tank_control.core.control.kinds import registry
from tank_control.core.control.kinds.base import resolve
from tank_control.core.loop import run_loop
from tank_control.core.scenario import build
from tank_control.nodes.live_rebuild import LiveRebuild

ACCEPTED, SWITCH, END = 40, 55, 80       # ticks (1 s): after the setpoint steps of 5 s, 20 s


def params() -> dict:
    p = params_file.read(SCENARIOS / 'tank_mpcs_qp.yaml')
    p['plant'].update({'noise_std': [0.02, 0.01], 'seed': 3})
    ref = p['reference']
    ref.update({'setpoint.h.times': [0.0, 5.0], 'setpoint.h.values': [81.0, 83.0],
                'setpoint.T_out.times': [0.0, 20.0], 'setpoint.T_out.values': [33.5, 34.5]})
    return p


def run(offloaded: bool):
    built = build(params())
    kind = built.controller_setup.kind
    changed = frozenset({'mpcs.horizon'})
    settings = resolve(kind, {**built.controller_setup.settings.values, 'mpcs.horizon': 300},
                       given=())
    state = {'controller': built.controller, 'rebuild': None}

    class Node:        # the node's sampling: the change accepted at ACCEPTED, switched at SWITCH
        output_names = built.controller.output_names
        input_names = built.controller.input_names
        disturbance_names = built.controller.disturbance_names
        sample_time = built.controller.sample_time

        def step(self, t, y, r, d):
            k, running = round(t), state['controller']
            if offloaded and k == ACCEPTED:
                state['rebuild'] = LiveRebuild(kind, copy.deepcopy(running), settings, changed,
                                               {'mpcs.horizon': 600}, gen=k, trial=None,
                                               u_last=None)
            if k == SWITCH:
                if offloaded:
                    assert state['rebuild'].wait(600.0)
                    new, u = state['rebuild'].switch(running, k, t, y, r, d)
                else:
                    new, u = registry.step_with_changes(kind, running, settings, changed,
                                                        t, y, r, d)
                state['controller'] = new
                return u
            return running.step(t, y, r, d)
    trace = run_loop(built.plant, Node(), built.reference, sample_time=built.sample_time,
                     duration=float(END), noise=built.noise.sample)
    return trace, state['controller']


def test_a_horizon_change_built_off_the_sampling_path_equals_the_change_at_its_sample():
    offloaded, controller = run(True)
    in_process, reference = run(False)
    assert controller.config.horizon == reference.config.horizon == 300
    for name in offloaded.names:
        assert np.array_equal(offloaded[name], in_process[name]), name
    # the running MPCS kept its law until the switch: unchanged until then
    plain, _ = run_loop_without_change()
    assert np.array_equal(plain['u.F_H'][:SWITCH], offloaded['u.F_H'][:SWITCH])
    assert not np.array_equal(plain['u.F_H'][SWITCH + 1:], offloaded['u.F_H'][SWITCH + 1:])


def run_loop_without_change():
    built = build(params())
    trace = run_loop(built.plant, built.controller, built.reference,
                     sample_time=built.sample_time, duration=float(END),
                     noise=built.noise.sample)
    return trace, built.controller
