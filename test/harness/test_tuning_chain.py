"""The shipped tuning chain (config/fopdt_ms_autotune.yaml: relay test → Ms = 1.4 PID design →
preview → apply at 150 s → verification step) in-process and over ROS in lockstep, and what
the harness shows of a loop: ``tank-control analyze`` and ``analysis.png``.

The claim of the file is checked against independent computations: the realised Ms of the
applied gains on the true plant (the plant section's FOPDT, exact ZOH, the implemented PID)
from the frequency module, the verification numbers against each other."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from support import CONFIG
from support.relay import run_logged

from tank_control.core import params_file
from tank_control.core.analysis import frequency as fr
from tank_control.core.trace import Trace
from tank_control.harness import analysis
from tank_control.harness.runner import run

SCENARIO = CONFIG / 'fopdt_ms_autotune.yaml'


def test_shipped_chain_keeps_its_claim_in_process():
    params = params_file.read(SCENARIO)
    trace, built, log = run_logged(params, float(params['harness']['duration']))
    states = [s for _, s in log]
    assert states == ['idle', 'settling', 'relay', 'measuring', 'proposed', 'running']
    assert dict((s, t) for t, s in log)['running'] == pytest.approx(150.0)   # apply_time
    values = built.controller_values()
    # the applied gains are the proposal, designed for Ms = 1.4 on the identified model
    for name in ('kp', 'ti', 'td', 'b', 'c'):
        assert values[name] == pytest.approx(values[f'autotune.proposed_{name}'])
    assert values['autotune.proposed_ms'] == pytest.approx(1.4, rel=1e-3)
    assert values['robustness.ms'] == pytest.approx(values['autotune.proposed_ms'])
    # claim 1: on the true plant (plant section) the implemented loop's Ms is 1.4 ± 3 %
    plant = params['plant']
    loop = fr.pid_feedback_discrete(values['kp'], values['ti'], values['td'], values['n'],
                                    sample_time=values['sample_time']) * fr.fopdt_zoh(
        plant['gain'], plant['time_constant'], plant['dead_time'], values['sample_time'])
    assert fr.margins(loop).ms == pytest.approx(1.4, rel=0.03)
    assert fr.closed_loop_stable(loop)
    # claim 2: the verification step's overshoot and IAE within 10 % of the prediction
    assert values['autotune.verify_state'] == 'ok' and values['autotune.warning'] == ''
    assert values['autotune.verify_step_size'] == 5.0
    assert values['autotune.verify_overshoot_measured'] == pytest.approx(
        values['autotune.verify_overshoot_predicted'], rel=0.10)
    assert values['autotune.verify_iae_measured'] == pytest.approx(
        values['autotune.verify_iae_predicted'], rel=0.10)
    # the step was internal and removed: the output is back at the reference's 100
    tail = trace['t'] > float(params['harness']['duration']) - 10.0
    assert abs(np.mean(trace['y.y'][tail]) - 100.0) < 0.5


def test_chain_lockstep_over_ros_equals_in_process(tmp_path, ros_env):
    """Every signal equal to 1e-9, and the controller ends with the same values (applied
    gains, identified model, proposal, verification, robustness) in both runs."""
    ros = run(SCENARIO, tmp_path / 'ros', rtf=0.0, env=ros_env)
    ref = run(SCENARIO, tmp_path / 'ref', in_process=True)
    a, b = Trace.read_csv(ros.files['trace']), Trace.read_csv(ref.files['trace'])
    assert len(a) == len(b)
    for name in b.columns:
        np.testing.assert_allclose(a.columns[name], b.columns[name], rtol=0, atol=1e-9,
                                   err_msg=name)
    pa, pb = (r.metrics['controller']['parameters'] for r in (ros, ref))
    keys = [k for k in pb if k.startswith(('autotune.', 'robustness.'))
            or k in ('kp', 'ti', 'td', 'b', 'c')]
    for key in keys:
        if isinstance(pb[key], float):
            assert pa[key] == pytest.approx(pb[key], rel=1e-9, abs=1e-12), key
        else:
            assert pa[key] == pb[key], key
    assert pa['autotune.state'] == 'running' and pa['autotune.verify_state'] == 'ok'
    for result in (ros, ref):
        assert result.files['analysis'].stat().st_size > 10_000
        analysis = result.metrics['loop_analysis']
        assert set(analysis) == {'plant (fopdt K=0.05 T=10 s L=3 s)',
                                 f"identified model ({pb['robustness.model']})"}


def analyze(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, '-m', 'tank_control.harness.cli', 'analyze', *args],
                          capture_output=True, text=True, timeout=300)


def test_analyze_prints_the_robustness_table_without_running():
    """[DeadTimeNotes]'s ZN PID (config/fopdt_zn.yaml) on its FOPDT: the numbers of the frequency module,
    and an override changes them as it would change the run."""
    out = analyze(str(CONFIG / 'fopdt_zn.yaml'))
    assert out.returncode == 0, out.stderr
    loop = fr.pid_feedback_discrete(70.92, 5.5, 1.32, sample_time=0.1) * fr.fopdt_zoh(
        0.05, 10.0, 3.0, 0.1)
    m = fr.margins(loop)
    row = next(line for line in out.stdout.splitlines() if line.startswith('| plant'))
    cells = [c.strip() for c in row.strip('|').split('|')]
    assert cells[1] == 'yes'
    assert float(cells[2]) == pytest.approx(m.gain_margin, rel=2e-3)
    assert float(cells[3]) == pytest.approx(m.phase_margin, abs=0.05)
    assert float(cells[4]) == pytest.approx(m.ms, rel=2e-3)
    assert analysis.analyze(CONFIG / 'fopdt_zn.yaml') == out.stdout     # the same table
    slower = analysis.analyze(CONFIG / 'fopdt_zn.yaml', ('plant.dead_time=6.0',))
    assert '| NO |' in slower
    assert '| T_out | h closed |' in analysis.analyze(CONFIG / 'tank_two_loop.yaml')   # per loop
    bad = analyze(str(CONFIG / 'fopdt_zn.yaml'), '--set', 'controller.kpp=1')
    assert bad.returncode == 2 and 'did you mean kp' in bad.stderr


def test_run_writes_analysis_png_for_a_siso_loop_and_per_loop_for_the_two_loop_pi(tmp_path):
    """A SISO loop's cases, and the two-loop PI's loops (test/harness/
    test_two_loop_run_analysis.py: the same numbers as ``analyze --json``; MPCS: none)."""
    pid = run(CONFIG / 'fopdt_zn.yaml', tmp_path / 'zn', in_process=True, duration=20.0)
    assert pid.files['analysis'].exists()
    metrics = json.loads(pid.files['metrics'].read_text())
    assert metrics['loop_analysis']['plant (fopdt K=0.05 T=10 s L=3 s)']['stable'] is True
    tank = run(CONFIG / 'tank_two_loop.yaml', tmp_path / 'tank', in_process=True, duration=20.0)
    assert tank.files['analysis'] == tmp_path / 'tank' / 'analysis.png'
    assert tank.metrics['loop_analysis']['T_out (h closed)']['stable'] is True
