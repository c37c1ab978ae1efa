"""`tank-control analyze FILE [--plot OUT.png] [--json]`: a loop's margins without running it
(issue 33 §2): SISO loops of kinds that describe themselves, the mixing tank's two-loop PI per
loop (the other loop open and closed), and MPCS, which says why it has none."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from tank_control.core import params_file, scenario
from tank_control.core.scenario_loops import loop_cases
from tank_control.core.analysis.robustness import predict
from tank_control.core.analysis.two_loop import LinearisedTank, TwoLoopAnalysis
from tank_control.harness import cli
from tank_control.harness.analysis import predicted_step


def analyze(capsys, *args: str) -> str:
    assert cli.main(['analyze', *args]) == 0
    return capsys.readouterr().out


def test_json_and_plot_of_a_siso_loop(capsys, tmp_path):
    out = tmp_path / 'loop.png'
    data = json.loads(analyze(capsys, 'config/ipdt_pid.yaml', '--json', '--plot', str(out)))
    assert out.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    [plant] = [row for row in data['loops'] if row['model'].startswith('plant')]
    case = loop_cases(params_file.read('config/ipdt_pid.yaml'))[0]
    report = case.report()
    assert plant['stable'] is True
    for key, value in (('gain_margin', report.gain_margin), ('phase_margin', report.phase_margin),
                       ('ms', report.ms), ('delay_margin', report.delay_margin)):
        assert plant[key] == pytest.approx(value, rel=1e-12)
    table = analyze(capsys, 'config/ipdt_pid.yaml')             # the table says the same
    assert f'{report.ms:.3g}' in table and f'{report.phase_margin:.1f}' in table


@pytest.mark.parametrize('path', ['config/ipdt_pid.yaml', 'config/fopdt_zn.yaml'])
def test_the_predicted_step_equals_a_simulation_of_the_loop(path):
    """The plot's step (inverse FFT of Y/R on the unit circle) against the project's time-domain
    simulation of the same discrete PID on the exact model (``robustness.predict``)."""
    sections = params_file.read(path)
    case = loop_cases(sections)[0]
    t, y = predicted_step(case)
    config = scenario.controller_setup(scenario.node_values(sections, 'controller'),
                                       given=()).settings.config
    simulated = predict(case.model, config)
    assert np.max(np.abs(np.interp(simulated.t, t, y) - simulated.setpoint)) < 1e-6
    assert y[-1] == pytest.approx(1.0, abs=1e-6)                 # integral action: no offset


def test_two_loop_pi_margins_per_loop_with_the_other_open_and_closed(capsys, tmp_path):
    data = json.loads(analyze(capsys, 'config/tank_two_loop.yaml', '--json', '--plot',
                              str(tmp_path / 'two.png')))
    sections = params_file.read('config/tank_two_loop.yaml')
    plant = scenario.plant_setup(scenario.node_values(sections, 'plant')).model
    config = scenario.controller_setup(scenario.node_values(sections, 'controller'),
                                       given=()).settings.config
    expected = TwoLoopAnalysis(LinearisedTank.from_config(plant), config).report()
    rows = {(r['loop'], r['other_loop']): r for r in data['loops']}
    assert len(rows) == 4
    for (loop, other), row in rows.items():
        key = loop if other.endswith('open') else f'{loop}|{other.split()[0]} closed'
        margins = expected[key]
        for name in ('phase_margin', 'ms', 'delay_margin'):
            assert row[name] == pytest.approx(margins[name], rel=1e-12), (loop, other, name)
        gm = margins['gain_margin']
        assert row['gain_margin'] == (None if math.isinf(gm) else pytest.approx(gm, rel=1e-12))
    assert (tmp_path / 'two.png').stat().st_size > 0


def test_mpcs_says_why_it_has_no_margins(capsys):
    out = analyze(capsys, 'config/scenarios/tank_mpcs_qp.yaml')
    assert 'no loop margins' in out and 'nonlinear' in out and len(out.splitlines()) == 1
    data = json.loads(analyze(capsys, 'config/scenarios/tank_mpcs_qp.yaml', '--json'))
    assert data['loops'] == [] and 'no loop margins' in data['reason']
