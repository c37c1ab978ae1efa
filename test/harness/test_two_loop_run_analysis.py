"""A run of the mixing tank's two-loop PI writes each loop's margins (the other loop open and
closed) into metrics.json ``loop_analysis`` and draws them in analysis.png — the numbers of
``tank-control analyze --json`` for the same file; an MPCS run says in one line why it has
none. The lockstep run writes the same (test/harness/test_scenarios_ros.py, the mixing tank)."""
from __future__ import annotations

import json

import pytest
from support import CONFIG

from tank_control.harness import cli
from tank_control.harness.runner import run

PNG = b'\x89PNG\r\n\x1a\n'


@pytest.mark.parametrize('path', [CONFIG / 'tank_two_loop.yaml',
                                  CONFIG / 'scenarios' / 'tank_pi_decoupled.yaml'])
def test_a_two_loop_run_writes_the_margins_analyze_gives(tmp_path, capsys, path):
    result = run(path, tmp_path / 'run', duration=300.0, in_process=True)
    assert result.files['analysis'].read_bytes()[:8] == PNG
    on_disk = json.loads(result.files['metrics'].read_text())
    analysis = on_disk['loop_analysis']
    assert cli.main(['analyze', str(path), '--json']) == 0
    expected = json.loads(capsys.readouterr().out)
    assert set(analysis) == {'h (T_out open)', 'h (T_out closed)', 'T_out (h open)',
                             'T_out (h closed)'}
    assert len(expected['loops']) == 4
    for row in expected['loops']:
        got = analysis[f'{row["loop"]} ({row["other_loop"]})']
        assert got['model'] == expected['two_loop']
        for key, value in row.items():
            assert got[key] == value, (row['loop'], row['other_loop'], key)
    # the level loop with the temperature loop closed: stable, a finite Ms
    assert analysis['h (T_out closed)']['stable'] is True
    assert 1.0 <= analysis['h (T_out closed)']['ms'] < 10.0


def test_an_mpcs_run_says_why_it_has_no_loop_margins(tmp_path):
    result = run(CONFIG / 'scenarios' / 'tank_mpcs_linear.yaml', tmp_path / 'run',
                 duration=100.0, in_process=True)
    note = result.metrics['loop_analysis']
    assert isinstance(note, str) and note.startswith('no loop to analyse: controller mpcs:')
    assert 'no loop margins' in note
    assert 'analysis' not in result.files and not (tmp_path / 'run' / 'analysis.png').exists()
