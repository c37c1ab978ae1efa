"""[DeadTimeNotes]'s sampling-time advice ([DeadTimeNotes] §1.2): T ≈ 0.3·L (Oppelt) and T ≈ (0.1…0.3)·Tu
(Ziegler–Nichols), reported as ``sampling.warning`` by the PID kinds on their process model."""
from __future__ import annotations

import math

import pytest

from tank_control.core.control.kinds import pid as pid_kind
from tank_control.core.control.kinds import relay_autotune as relay_kind
from tank_control.core.control.kinds.base import resolve
from tank_control.core.tuning.model import ProcessModel
from tank_control.core.tuning.sampling import sampling_advice, ultimate_period

#: [DeadTimeNotes]'s example process ([Checks] §1): K = 0.05, T = 10 s, L = 3 s; Tu = 10.824 s (checked)
MODEL_001 = ProcessModel('fopdt', 0.05, 3.0, 10.0)


def test_001_example_bounds():
    """[DeadTimeNotes]'s own numbers: Oppelt's T = 0.9 s for L = 3 s is within the advice; ZN's range for
    T_krit = 11 s is 1.1–3.3 s, for the exact Tu 10.824 s it ends at 3.247 s."""
    assert ultimate_period(MODEL_001) == pytest.approx(10.824, abs=5e-4)
    assert sampling_advice(0.1, MODEL_001) == ''
    assert sampling_advice(0.9, MODEL_001) == ''
    oppelt = sampling_advice(1.0, MODEL_001)
    assert oppelt.startswith('sample_time 1 s is above 0.3·L = 0.9 s') and 'Tu' not in oppelt
    both = sampling_advice(3.3, MODEL_001)
    assert '0.3·L = 0.9 s' in both and '0.3·Tu = 3.247 s' in both
    assert 'fopdt K=0.05 T=10 s L=3 s' in both


def test_ipdt_tu_is_four_dead_times_and_no_model_means_no_advice():
    """IPDT: Tu = 4·To ([Viteckova] eq. 1), so 0.3·L is the tighter bound; no model, no advice; a
    delay-free first-order model has no ultimate point (phase above −90°)."""
    ipdt = ProcessModel('ipdt', 0.05, 5.0)
    assert ultimate_period(ipdt) == pytest.approx(20.0, rel=1e-6)
    assert sampling_advice(1.5, ipdt) == ''
    assert '0.3·L = 1.5 s' in sampling_advice(1.6, ipdt)
    assert sampling_advice(100.0, None) == ''
    lag = ProcessModel('fopdt', 1.0, 0.0, 10.0)
    assert math.isinf(ultimate_period(lag)) and sampling_advice(5.0, lag) == ''


def test_pid_kind_reports_the_advice_and_follows_a_model_change():
    values = {'tuning.gain': 0.05, 'tuning.time_constant': 10.0, 'tuning.dead_time': 3.0,
              'sample_time': 0.1, 'kp': 20.0, 'ti': 8.0}
    controller = pid_kind.KIND.build(resolve(pid_kind.KIND, values))
    assert pid_kind.KIND.results(controller)['sampling.warning'] == ''
    short = resolve(pid_kind.KIND, {**values, 'tuning.dead_time': 0.3},
                    given={'tuning.dead_time'})
    pid_kind.KIND.update(controller, short, frozenset({'tuning.dead_time'}))
    warning = pid_kind.KIND.results(controller)['sampling.warning']
    assert warning == sampling_advice(0.1, ProcessModel('fopdt', 0.05, 0.3, 10.0))
    assert '0.3·L = 0.09 s' in warning
    # without a model: nothing to advise on
    none = pid_kind.KIND.build(resolve(pid_kind.KIND, {'kp': 1.0, 'ti': 10.0}))
    assert pid_kind.KIND.results(none)['sampling.warning'] == ''


def test_relay_autotune_kind_declares_the_advice():
    """The auto-tuner has no model before it identified one: the advice is empty, declared."""
    tuner = relay_kind.KIND.build(resolve(relay_kind.KIND, {}))
    assert relay_kind.KIND.results(tuner)['sampling.warning'] == ''
