"""The robustness panel's analysis (dashboard/robustness.py) from node parameter values: the
margins are those of the project's loop analysis for the same settings, a transfer-function
plant equal to an FOPDT gives the FOPDT's margins, and loops the analysis cannot describe get
one line saying why."""
from __future__ import annotations

import math
import threading

import numpy as np
import pytest

from tank_control.core.analysis.robustness import loop_report
from tank_control.core.control.pid import PidConfig
from tank_control.core.tuning.model import ProcessModel
from tank_control.dashboard.robustness import RobustnessWorker, loop_analysis

PLANT = {'plant': 'fopdt', 'sample_time': 0.1, 'gain': 0.05, 'time_constant': 10.0,
         'dead_time': 3.0}
PID = {'controller': 'pid', 'sample_time': 0.1, 'output_names': ['y'], 'input_names': ['u'],
       'kp': 20.0, 'ti': 12.0, 'td': 1.0, 'u_min': 0.0, 'u_max': 1e4}
KEYS = ('gain_margin', 'phase_margin', 'ms', 'mt', 'delay_margin', 'wc', 'w180')


def test_margins_are_those_of_the_loop_report_of_the_same_settings():
    out = loop_analysis(PLANT, PID)
    assert out['available'] and out['reason'] == ''
    report = loop_report(ProcessModel('fopdt', 0.05, 3.0, 10.0),
                         PidConfig(kp=20.0, ti=12.0, td=1.0, sample_time=0.1))
    margins = out['cases'][0]['margins']
    assert margins['stable'] is report.stable is True
    for key in KEYS:
        assert margins[key] == pytest.approx(getattr(report, key), rel=1e-9), key
    # the curves: L = C·G on the grid, |L| = 1 at the gain crossover within the grid's step
    w = np.asarray(out['w'])
    mag = np.asarray(out['cases'][0]['mag'])
    assert np.all(np.diff(w) > 0) and w[-1] == pytest.approx(math.pi / 0.1, rel=1e-6)
    assert np.interp(math.log(report.wc), np.log(w), np.log(mag)) == pytest.approx(0.0,
                                                                                  abs=1e-3)
    re, im = np.asarray(out['cases'][0]['re']), np.asarray(out['cases'][0]['im'])
    assert np.allclose(np.hypot(re, im), mag, rtol=1e-12)
    # the Nyquist curve's closest approach to −1 is 1/Ms
    assert np.min(np.hypot(re + 1, im)) == pytest.approx(1 / report.ms, rel=1e-3)


def test_a_transfer_function_equal_to_the_fopdt_has_its_margins():
    tf = {'plant': 'transfer_function', 'num': [0.05], 'den': [10.0, 1.0], 'dead_time': 3.0}
    by_tf = loop_analysis(tf, PID)['cases'][0]['margins']
    by_model = loop_analysis(PLANT, PID)['cases'][0]['margins']
    for key in KEYS:
        assert by_tf[key] == pytest.approx(by_model[key], rel=1e-6), key


def test_a_higher_gain_lowers_the_gain_margin_by_the_same_factor():
    low = loop_analysis(PLANT, PID)['cases'][0]['margins']
    high = loop_analysis(PLANT, {**PID, 'kp': 40.0})['cases'][0]['margins']
    # the phase of L does not depend on kp: same phase crossover, |L| doubled there
    assert high['w180'] == pytest.approx(low['w180'], rel=1e-6)
    assert high['gain_margin'] == pytest.approx(low['gain_margin'] / 2, rel=1e-6)


@pytest.mark.parametrize('plant, controller, says', [
    ({'plant': 'mixing_tank'}, PID, 'plant mixing_tank'),
    (PLANT, {'controller': 'mpcs'}, 'controller mpcs'),
    (None, PID, 'no plant node'),
    (PLANT, None, 'no controller node'),
    ({**PLANT, 'gain': 'abc'}, PID, 'cannot be analysed'),
])
def test_a_loop_the_analysis_cannot_describe_gets_one_line(plant, controller, says):
    out = loop_analysis(plant, controller)
    assert not out['available'] and out['cases'] == []
    assert says in out['reason'] and '\n' not in out['reason']


def test_the_worker_publishes_once_per_change():
    got, seen = [], threading.Event()

    def publish(message):
        got.append(message)
        seen.set()
    worker = RobustnessWorker(publish)
    try:
        worker.submit(PLANT, PID)
        assert seen.wait(60)
        seen.clear()
        worker.submit(PLANT, PID)                    # unchanged: nothing new
        worker.submit(PLANT, {**PID, 'kp': 40.0})
        assert seen.wait(60)
    finally:
        worker.stop()
    assert [m['type'] for m in got] == ['robustness', 'robustness']
    assert 'kp 40' in got[1]['controller'] and worker.latest is got[1]
