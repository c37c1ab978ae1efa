"""The sweep summary reports a margin's worst case on its bad side (issue 33 §1): the smallest
gain, phase and delay margin, and its low tail (p5), never the p95 of a margin."""
from __future__ import annotations

from types import SimpleNamespace

from tank_control.harness.sweep import summarize, summary_markdown


def _rows():
    rows = []
    for k in range(21):                    # phase margin 20…60°, overshoot 0…20 %
        rows.append({'run': k, 'scenario': 's', 'sample': k, 'status': 'ok', 'reason': '',
                     'plant.dead_time': 4.0 + 0.1 * k, 'y.overshoot_pct': float(k),
                     'loop.phase_margin': 60.0 - 2.0 * k, 'loop.gain_margin': 3.0 - 0.1 * k,
                     'loop.delay_margin': 2.0 - 0.05 * k})
    return rows


def test_margins_show_their_minimum_and_low_tail():
    summary = summarize(_rows(), SimpleNamespace(title='t', claim=''))
    metrics = summary['scenarios']['s']['metrics']
    assert metrics['loop.phase_margin']['worst'] == 20.0
    assert metrics['loop.phase_margin']['worst_at'] == {'plant.dead_time': 6.0}
    assert metrics['y.overshoot_pct']['worst'] == 20.0
    table = {line.split('|')[2].strip(): [c.strip() for c in line.split('|')[3:7]]
             for line in summary_markdown(summary).splitlines() if line.startswith('| s |')}
    # runs, p50, bad-side tail, worst
    assert table['loop.phase_margin'] == ['21', '40', '22', '20']
    assert table['loop.gain_margin'] == ['21', '2', '1.1', '1']
    assert table['loop.delay_margin'] == ['21', '1.5', '1.05', '1']
    assert table['y.overshoot_pct'] == ['21', '10', '19', '20']
