"""plot.png and the compare overlay, checked on the matplotlib Figure (lines, texts, axis limits):
input limits drawn, gains and ``--set`` overrides in the title, a side table of metrics, the
auto-tuner's state changes marked, a derivative kick clipped (and marked) instead of squashing
the input axis, one colour per run in an overlay and legends outside the axes."""
from __future__ import annotations

import json

import numpy as np
import pytest
from support import CONFIG, SCENARIOS

from tank_control.core.trace import Trace
from tank_control.harness import cli
from tank_control.harness.plotting import RunPlot, figure_runs, plt, run_plot


def axis_of(fig, ylabel_start: str):
    (ax,) = [a for a in fig.axes if a.get_ylabel().startswith(ylabel_start)]
    return ax


def hlines_at(ax) -> set[float]:
    return {float(line.get_ydata()[0]) for line in ax.get_lines()
            if len(set(np.asarray(line.get_ydata(), dtype=float))) == 1
            and list(line.get_xdata()) == [0, 1]}


def test_run_plot_shows_limits_gains_overrides_metrics_and_autotune_states(tmp_path, capsys):
    out = tmp_path / 'run'
    assert cli.main(['run', str(SCENARIOS / 'fopdt_autotune_scheduled.yaml'), '--out', str(out),
                     '--in-process', '--quiet', '--set', 'controller.kp=21.0']) == 0
    capsys.readouterr()
    metrics = json.loads((out / 'metrics.json').read_text())
    from tank_control.core.trace import Trace as CoreTrace
    trace = CoreTrace.read_csv(out / 'trace.csv')
    fig = figure_runs([run_plot('at', trace, metrics)], title=metrics['title'])
    try:
        title = fig._suptitle.get_text()
        gains = metrics['controller']['final_gains']
        assert f"gains: kp {gains['kp']:.4g}, ti {gains['ti']:.4g}" in title
        assert '--set controller.kp=21.0' in title
        assert metrics['overrides'] == ['controller.kp=21.0']
        # input limits 0 and 10000: 0 in view (u starts there), 10000 named once in the title
        u_ax = axis_of(fig, 'manipulated input')
        assert hlines_at(u_ax) == {0.0}
        labels = u_ax.get_legend_handles_labels()[1]
        assert 'limit 0' in labels and not any('off scale' in label for label in labels)
        assert title.count('off scale') == 1 and 'limits off scale: u ≤ 1e+04' in title
        assert u_ax.get_ylim()[1] < 3000.0               # the far limit does not squash u
        # the state changes, as the tuner went through them, marked with their names
        states = metrics['run']['controller_states']
        assert [s for _, s in states] == ['settling', 'relay', 'measuring', 'tuned', 'running']
        assert states[0][0] == pytest.approx(60.0)
        y_ax = axis_of(fig, 'output')
        marked = {(round(float(t.get_position()[0]), 6), t.get_text().strip()) for t in y_ax.texts}
        assert marked == {(round(t, 6), s) for t, s in states}
        vlines = {float(line.get_xdata()[0]) for line in u_ax.get_lines()
                  if list(line.get_ydata()) == [0, 1]}
        assert vlines == {t for t, _ in states}
        # the names do not overlap (tuned and running are 0.1 s apart here)
        fig.canvas.draw()
        boxes = [t.get_window_extent(fig.canvas.get_renderer()) for t in y_ax.texts]
        assert not [(a, b) for i, a in enumerate(boxes) for b in boxes[i + 1:] if a.overlaps(b)]
        # the side table: this run's metrics, as metrics.json has them
        table = '\n'.join(t.get_text() for t in fig.texts)
        assert f"{metrics['outputs']['y']['iae']:.4g}" in table and 'y IAE' in table
        assert 'u range' in table
    finally:
        plt.close(fig)


def kick_trace(offset: float = 0.0) -> Trace:
    t = np.arange(0.0, 100.0, 0.1)
    rng = np.random.default_rng(1)
    u = 1.0 + 0.2 * np.sin(t / 5) + 0.01 * rng.standard_normal(t.size) + offset
    u[100] = 500.0                       # a derivative kick at a setpoint step: one sample
    y = np.where(t >= 10.0, 1.0 - np.exp(-(t - 10.0) / 5.0), 0.0)
    return Trace.ordered({'t': t, 'y.y': y + offset, 'r.y': (t >= 10.0).astype(float),
                          'u.u': u, 'u.v': u * 0.5})


def test_a_derivative_kick_is_clipped_and_marked_instead_of_squashing_the_input_axis():
    trace = kick_trace()
    fig = figure_runs([RunPlot('kick', trace, limits={'u': (-5.0, 600.0)})])
    try:
        u_ax = axis_of(fig, 'manipulated input')
        lo, hi = u_ax.get_ylim()
        rest = np.delete(trace.columns['u.u'], 100)
        assert lo <= rest.min() and rest.max() <= hi               # every other sample shown
        assert hi - lo < 2.0                                       # not 0 … 500
        clipped = [line for line in u_ax.get_lines()
                   if line.get_label().startswith('u: 1 samples clipped')]
        assert len(clipped) == 1 and 'to 500' in clipped[0].get_label()
        assert list(clipped[0].get_xdata()) == [trace.t[100]]
        assert list(clipped[0].get_ydata()) == [hi]                # at the top edge
        assert 'u ≤ 600' in fig._suptitle.get_text().split('limits off scale: ')[1]
    finally:
        plt.close(fig)


def test_without_spikes_the_input_axis_shows_the_full_range():
    t = np.arange(0.0, 50.0, 0.1)
    u = np.where(t < 10.0, 0.0, 3.0)                          # a step: rare but real
    trace = Trace.ordered({'t': t, 'y.y': u, 'r.y': u, 'u.u': u})
    fig = figure_runs([RunPlot('step', trace)])
    try:
        lo, hi = axis_of(fig, 'manipulated input').get_ylim()
        assert lo < 0.0 and hi > 3.0
    finally:
        plt.close(fig)


def test_overlay_keeps_one_colour_per_run_and_legends_outside_the_axes():
    runs = [RunPlot('a', kick_trace()), RunPlot('b', kick_trace(0.3)), RunPlot('c', kick_trace(0.6))]
    fig = figure_runs(runs, title='comparison')
    try:
        colours: dict[str, set] = {}
        for ax in fig.axes:
            for line in ax.get_lines():
                run = line.get_label().split(':')[0]
                if run in ('a', 'b', 'c') and not line.get_label().count('clipped'):
                    colours.setdefault(run, set()).add(line.get_color())
        assert all(len(c) == 1 for c in colours.values()), colours
        assert len({c.pop() for c in colours.values()}) == 3
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        for ax in fig.axes:
            legend = ax.get_legend()
            assert legend is not None
            assert legend.get_window_extent(renderer).x0 >= ax.get_window_extent(renderer).x1
    finally:
        plt.close(fig)


def test_a_constant_channel_is_named_in_the_title_not_drawn_flat():
    t = np.arange(0.0, 50.0, 0.1)
    y = np.where(t < 10.0, 0.0, 1.0)
    trace = Trace.ordered({'t': t, 'y.y': y, 'r.y': y, 'u.u': 2.0 * y, 'd.v': np.zeros(t.size),
                           'd.T_D': np.full(t.size, 33.0), 'd.F_D': np.where(t < 20.0, 12.0, 15.0)})
    fig = figure_runs([RunPlot('c', trace)])
    try:
        labels = [label for ax in fig.axes for label in ax.get_legend_handles_labels()[1]]
        assert 'v' not in labels and 'T_D' not in labels and 'F_D' in labels
        assert 'constant: v 0, T_D 33 °C' in fig._suptitle.get_text()
        assert len(fig.axes) == 3          # y, u, F_D: no flat panel
    finally:
        plt.close(fig)


def test_the_metrics_table_sits_beside_the_legends_inside_the_figure():
    """No empty right third: the panels reach well past half the width, the table follows the
    widest legend (a long one here: the clipped kick) and ends inside the figure."""
    trace = kick_trace()
    runs = [RunPlot('a long run label', trace, table=[('y IAE', '1.234'), ('u range', '0 … 12345.678')])]
    fig = figure_runs(runs)
    try:
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        width = fig.get_window_extent(renderer).x1
        assert all(ax.get_position().x1 >= 0.6 for ax in fig.axes)
        (table,) = [t for t in fig.texts if 'y IAE' in t.get_text()]
        box = table.get_window_extent(renderer)
        assert box.x1 <= width
        assert box.x0 >= max(ax.get_legend().get_window_extent(renderer).x1 for ax in fig.axes)
    finally:
        plt.close(fig)


def test_no_plots_draws_no_figure_and_writes_the_same_metrics(tmp_path, capsys):
    """``--no-plots`` (run and compare): neither plot.png, analysis.png nor overlay.png; the
    trace and metrics.json (loop analysis included) equal a drawn run's."""
    scenario = str(CONFIG / 'ipdt_pid.yaml')
    drawn, bare = tmp_path / 'drawn', tmp_path / 'bare'
    assert cli.main(['compare', scenario, '--out', str(drawn), '--in-process', '--quiet',
                     '--duration', '30']) == 0
    assert cli.main(['compare', scenario, '--out', str(bare), '--in-process', '--quiet',
                     '--duration', '30', '--no-plots']) == 0
    name = next(p.name for p in drawn.iterdir() if p.is_dir())
    assert {p.name for p in (drawn / name).glob('*.png')} == {'plot.png', 'analysis.png'}
    assert (drawn / 'overlay.png').exists()
    assert not list(bare.rglob('*.png'))
    assert 'overlay' not in capsys.readouterr().out.split('table:')[-1]

    def metrics(root):
        values = json.loads((root / name / 'metrics.json').read_text())
        values['run'].pop('wall_time'), values['run'].pop('ticks_per_s')
        return values
    assert metrics(bare) == metrics(drawn)
    assert metrics(bare)['loop_analysis']
    assert (bare / name / 'trace.csv').read_text() == (drawn / name / 'trace.csv').read_text()
