"""The tank comparison of docs/mpcs.md ("One schedule, every controller"): PI, decoupled PI,
auto-tuned decoupled PI, gain-scheduled PI, MPCS analytic and MPCS QP on one sequence, through
`tank-control compare --in-process`: one table with both outputs of every controller, the
interaction of each setpoint step on the other output in every run's metrics.json, and the
facts the page draws from it."""
from __future__ import annotations

import pytest

import json

from support import SCENARIOS

from tank_control.harness import cli

ROWS = ('tank_mpcs_two_loop', 'tank_mpcs_two_loop_decoupled', 'tank_mpcs_two_loop_autotuned',
        'tank_mpcs_two_loop_scheduled', 'tank_mpcs_analytic', 'tank_mpcs_qp')


@pytest.mark.slow
def test_one_schedule_every_controller(tmp_path, capsys):
    out = tmp_path / 'cmp'
    assert cli.main(['compare', *(str(SCENARIOS / f'{name}.yaml') for name in ROWS),
                     '--out', str(out), '--in-process', '--quiet', '--no-plots']) == 0
    capsys.readouterr()
    table = (out / 'comparison.md').read_text()
    assert 'coupling peak' in next(line for line in table.splitlines() if line.startswith('|'))
    for name in ROWS:
        assert f'| {name} | h |' in table and f'| {name} | T_out |' in table
    runs = {name: json.loads((out / name / 'metrics.json').read_text())['outputs']
            for name in ROWS}
    sequences = {name: [(s['t'], s['r_to']) for ch in ('h', 'T_out') for s in o[ch]['steps']]
                 for name, o in runs.items()}
    assert len({tuple(v) for v in sequences.values()}) == 1           # one schedule

    def t_dip(name):      # T_out's largest deviation on the level steps [°C]
        return max(abs(s['interaction']['T_out']['peak_signed']) for s in runs[name]['h']['steps'])

    decoupled = ('tank_mpcs_two_loop_decoupled', 'tank_mpcs_two_loop_autotuned')
    assert max(map(t_dip, decoupled)) < 1.0 < 2.5 < min(t_dip(n) for n in ROWS
                                                          if n not in decoupled)
    tuned = runs['tank_mpcs_two_loop_autotuned']
    assert max(s['overshoot_pct'] for ch in ('h', 'T_out') for s in tuned[ch]['steps']) < 1.0
    assert tuned['T_out']['iae'] == min(o['T_out']['iae'] for o in runs.values())
    assert runs['tank_mpcs_qp']['h']['iae'] == min(o['h']['iae'] for o in runs.values())
