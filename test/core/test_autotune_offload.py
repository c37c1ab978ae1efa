"""``autotune.design_time``: the relay test's identification and design run off the sampling
path (issue "operate a loop" §7). The result takes effect at a sample fixed by the loop's
time, so every clock mode and every machine load gives the same trace."""
from __future__ import annotations

import threading

import numpy as np
import pytest

from tank_control.core.control.kinds.registry import make_controller
from tank_control.core.tuning import identification as ident
from tank_control.core.tuning.model import ProcessModel

H = 0.1
SETTINGS = {'kp': 20.0, 'ti': 12.0, 'u_min': 0.0, 'u_max': 10000.0, 'sample_time': H,
            'autotune.relay_amplitude': 200.0, 'autotune.settle_time': 5.0,
            'autotune.settle_band': 0.5, 'autotune.max_amplitude': 20.0,
            'autotune.rule': 'zn_001', 'autotune.kind': 'pid'}


def run(design_time: float, steps: int = 2500) -> dict:
    """001's FOPDT (K 0.05, T 10 s, L 3 s) under the relay tuner from rest at r = 100."""
    controller = make_controller('relay_autotune', {**SETTINGS,
                                                    'autotune.design_time': design_time})
    plant = ProcessModel('fopdt', 0.05, 3.0, 10.0).plant()
    r = np.array([100.0])
    controller.start()
    u_out, states = [], []
    for k in range(steps):
        y = plant.outputs()
        u = controller.step(k * H, y, r, np.array([]))
        u_out.append(float(u[0]))
        states.append(controller.state)
        plant.step(u, np.array([0.0]), H)
    return {'u': np.array(u_out), 'states': states, 'status': controller.status}


def first(states: list[str], state: str) -> int:
    return states.index(state)


def test_the_result_takes_effect_design_time_later_and_equals_the_one_on_the_sampling_path():
    now, later = run(0.0), run(2.0)
    assert now['status']['ku'] == later['status']['ku']           # the same record, bit for bit
    assert now['status']['tu'] == later['status']['tu']
    assert now['status']['gains'] == later['status']['gains']
    k_now, k_later = first(now['states'], 'tuned'), first(later['states'], 'tuned')
    assert k_later - k_now == round(2.0 / H)                      # 20 samples later, exactly
    # until then the relay ran on: outputs at the relay's two levels
    relay = later['u'][k_now:k_later]
    levels = {round(v, 6) for v in now['u'][k_now - 300:k_now]}   # both relay levels
    assert {round(v, 6) for v in relay} <= levels
    # the PID takes over from the bias u0 in both cases: no jump beyond the relay's own step
    u0 = later['status']['u0']
    assert abs(later['u'][k_later] - u0) <= abs(now['u'][k_now] - now['status']['u0']) + 1.0


def test_a_deferred_result_gives_the_same_trace_whatever_the_worker_thread_takes(monkeypatch):
    """Determinism: the worker is slowed down until the sample that needs it; the trace equals
    the undisturbed one (the sample waits, it does not move)."""
    plain = run(2.0)
    slow = threading.Event()
    real = ident.identify_relay

    def slowed(*args, **kwargs):
        slow.wait(0.5)                      # the sampling thread reaches the due sample first
        return real(*args, **kwargs)
    monkeypatch.setattr(ident, 'identify_relay', slowed)
    delayed = run(2.0)
    assert np.array_equal(plain['u'], delayed['u']) and plain['states'] == delayed['states']


def test_the_identification_runs_in_another_thread_than_the_samples(monkeypatch):
    threads = []
    real = ident.identify_relay

    def recorded(*args, **kwargs):
        threads.append(threading.current_thread())
        return real(*args, **kwargs)
    monkeypatch.setattr(ident, 'identify_relay', recorded)
    run(2.0)
    assert threads and all(t is not threading.current_thread() for t in threads)
    threads.clear()
    run(0.0)
    assert threads == [threading.current_thread()]               # 0: on the sampling path


def test_an_abort_while_the_result_is_computed_drops_it():
    controller = make_controller('relay_autotune', {**SETTINGS, 'autotune.design_time': 5.0})
    plant = ProcessModel('fopdt', 0.05, 3.0, 10.0).plant()
    r = np.array([100.0])
    controller.start()
    k = 0
    while controller._job is None:            # noqa: SLF001 - the pending job is the state here
        u = controller.step(k * H, plant.outputs(), r, np.array([]))
        plant.step(u, np.array([0.0]), H)
        k += 1
        assert k < 3000, 'the relay test never completed its data'
    assert controller.abort()[0]
    for j in range(k, k + 100):
        u = controller.step(j * H, plant.outputs(), r, np.array([]))
        plant.step(u, np.array([0.0]), H)
    assert controller.state == 'aborted' and controller.proposal is None


@pytest.mark.parametrize('bad', [-1.0, 3601.0, float('nan')])
def test_design_time_is_checked(bad):
    from tank_control.core.params import ConfigError
    with pytest.raises(ConfigError, match='autotune.design_time'):
        make_controller('relay_autotune', {**SETTINGS, 'autotune.design_time': bad})


def test_on_the_wall_clock_no_sample_waits_for_the_design_and_the_switch_is_bumpless(
        monkeypatch):
    """controller_node in wall mode (``wall_clock``), ``design_time`` 0 (the default): the
    identification runs off the sampling path (here in the worker thread, where the test can
    hold it; the node's is a process: the next test); held there, the relay keeps sampling
    (no sample waits); the first sample after it is done switches to the PID from u0, with the
    gains of the inline design."""
    from tank_control.core.control import relay_autotune
    inline = run(0.0)
    monkeypatch.setattr(relay_autotune, '_wall_pool', relay_autotune._worker)
    gate = threading.Event()
    real = ident.identify_relay

    def held(*args, **kwargs):
        assert gate.wait(60.0)              # released by the sampling loop below
        return real(*args, **kwargs)
    monkeypatch.setattr(ident, 'identify_relay', held)
    controller = make_controller('relay_autotune', {**SETTINGS, 'autotune.design_time': 0.0})
    controller.wall_clock = True
    plant = ProcessModel('fopdt', 0.05, 3.0, 10.0).plant()
    r = np.array([100.0])
    controller.start()
    u_out, states = [], []
    k_done = None
    for k in range(2500):
        u = controller.step(k * H, plant.outputs(), r, np.array([]))
        u_out.append(float(u[0]))
        states.append(controller.state)
        plant.step(u, np.array([0.0]), H)
        if controller._job is not None and k_done is None:   # noqa: SLF001 - the pending job
            k_done = k + 30                 # 3 s of samples with the design held
        if k_done is not None and k == k_done:
            gate.set()
            assert controller._job.wait(60.0)                  # noqa: SLF001
    k_inline = first(inline['states'], 'tuned')
    k_tuned = first(states, 'tuned')
    # the relay ran on (its two levels) while the design was held: no sample waited for it
    assert k_tuned == k_done + 1
    assert {round(v, 6) for v in u_out[k_inline:k_tuned]} <= \
        {round(v, 6) for v in inline['u'][k_inline - 300:k_inline]}
    assert controller.status['gains'] == inline['status']['gains']
    # the PID takes over from the bias u0: no jump beyond the relay's own step
    u0 = controller.status['u0']
    assert abs(u_out[k_tuned] - u0) <= abs(inline['u'][k_inline] - inline['status']['u0']) + 1.0


def test_on_the_wall_clock_the_design_runs_in_another_process_with_the_same_result():
    """wall mode's worker is a process (no GIL shared with the sampling thread): the relay
    runs on until its result is there, which equals the inline design's."""
    inline = run(0.0)
    controller = make_controller('relay_autotune', {**SETTINGS, 'autotune.design_time': 0.0})
    controller.wall_clock = True
    plant = ProcessModel('fopdt', 0.05, 3.0, 10.0).plant()
    r = np.array([100.0])
    controller.start()
    states, waited = [], None
    for k in range(2500):
        u = controller.step(k * H, plant.outputs(), r, np.array([]))
        states.append(controller.state)
        plant.step(u, np.array([0.0]), H)
        if controller._job is not None and waited is None:    # noqa: SLF001 - the pending job
            assert controller._job.wait(120.0)                 # noqa: SLF001
            waited = k
    assert first(states, 'tuned') == waited + 1               # the first sample after it
    assert controller.status['ku'] == inline['status']['ku']
    assert controller.status['gains'] == inline['status']['gains']
