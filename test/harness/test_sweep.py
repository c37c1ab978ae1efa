"""tank-control sweep: specifications, one run = the in-process run, executors give identical
results (inline, local processes, a real dask.distributed LocalCluster), failures as rows,
resuming, the written table/summary/plots, and lockstep runs over ROS 2 in domains of their own."""
from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest

from support import CONFIG
from tank_control.core.analysis.metrics_row import flat_metrics
from tank_control.harness import cli, runner, sweep
from tank_control.harness.scenario_file import ScenarioError

MDP_PID = CONFIG / 'scenarios' / 'ipdt_mdp_pid_deadtime_plus20.yaml'
EXP_PI = CONFIG / 'scenarios' / 'ipdt_exp_pi.yaml'


def small_spec(**kw) -> sweep.SweepSpec:
    """Four grid points x two random samples on two scenarios, 120 s each (16 runs)."""
    base = dict(scenarios=(MDP_PID, EXP_PI),
                grid=(sweep.GridAxis.parse('plant.dead_time=±20%:2'),
                      sweep.GridAxis.parse('plant.gain=0.045,0.055')),
                random=(sweep.RandomAxis.parse('reference.disturbance.v.values[1]=uniform(-0.2,0)'),
                        sweep.RandomAxis.parse('plant.noise_std[0]=uniform(0,0.001)')),
                samples=2, seed=7, duration=120.0)
    base.update(kw)
    return sweep.SweepSpec(**base)


def metric_table(rows):
    """The deterministic part of a result table (everything but wall time)."""
    return [{k: v for k, v in row.items() if k not in sweep.NONDETERMINISTIC} for row in rows]


# --------------------------------------------------------------------------- specifications
def test_grid_forms():
    nominal = 5.0
    assert sweep.GridAxis.parse('plant.dead_time=±20%:5').values(nominal) == [4.0, 4.5, 5.0,
                                                                             5.5, 6.0]
    assert sweep.GridAxis.parse('plant.dead_time=+-10%:3').values(nominal) == [4.5, 5.0, 5.5]
    assert sweep.GridAxis.parse('plant.gain=0.04:0.06:3').values(None) == [0.04, 0.05, 0.06]
    assert sweep.GridAxis.parse('controller.tuning.rule=mdp,experimental').values(None) == [
        'mdp', 'experimental']
    axis = sweep.GridAxis.parse('reference.disturbance.v.values[1]=-0.1,-0.2')
    assert axis.target.label == 'reference.disturbance.v.values[1]'


@pytest.mark.parametrize('item, words', [
    ('plantt.gain=1,2', 'did you mean plant'),
    ('plant.gain', 'expected NODE.PARAM'),
    ('plant.gain=1:x:3', "'x' is not a number"),
    ('plant.gain=1:2:0', 'at least 1 point'),
])
def test_bad_grid_is_refused_with_the_reason(item, words):
    with pytest.raises(ScenarioError, match=words):
        sweep.GridAxis.parse(item)


@pytest.mark.parametrize('item, words', [
    ('plant.gain=gauss(0,1)', 'normal'),
    ('plant.gain=uniform(2,1)', 'a <= b'),
    ('plant.gain=normal(1,-1)', 'sigma'),
    ('plant.seed=randint(0,2.5)', 'integers'),
])
def test_bad_random_is_refused_with_the_reason(item, words):
    with pytest.raises(ScenarioError, match=words):
        sweep.RandomAxis.parse(item)


def test_unknown_parameter_and_bad_index_are_refused_before_anything_runs(tmp_path):
    spec = sweep.SweepSpec(scenarios=(MDP_PID,), grid=(sweep.GridAxis.parse(
        'plant.dead_tme=±20%:3'),))
    with pytest.raises(ScenarioError, match='did you mean dead_time'):
        sweep.cases(spec)
    spec = sweep.SweepSpec(scenarios=(MDP_PID,), grid=(sweep.GridAxis.parse(
        'reference.disturbance.v.values[5]=1'),))
    with pytest.raises(ScenarioError, match=r'index must name one of its elements'):
        sweep.cases(spec)
    with pytest.raises(ScenarioError, match='--samples'):
        sweep.cases(sweep.SweepSpec(scenarios=(MDP_PID,), random=(
            sweep.RandomAxis.parse('plant.gain=uniform(0.04,0.06)'),)))
    assert not any(tmp_path.iterdir())


def test_cases_cover_the_product_with_common_random_draws():
    spec = small_spec()
    all_cases = sweep.cases(spec)
    assert len(all_cases) == 2 * 2 * 2 * 2
    rng = np.random.default_rng(7)                 # the documented order: sample by sample
    expected = [(rng.uniform(-0.2, 0), rng.uniform(0, 0.001)) for _ in range(2)]
    for case in all_cases:
        drawn = (case.overrides['reference.disturbance.v.values[1]'],
                 case.overrides['plant.noise_std[0]'])
        assert drawn == expected[case.sample]
        values = case.scenario.params('reference')['disturbance.v.values']
        assert values[1] == drawn[0] and values[0] == 0.0
    dead_times = {name: sorted({c.overrides['plant.dead_time'] for c in all_cases
                                if c.scenario.name == name})
                  for name in ('ipdt_mdp_pid_deadtime_plus20', 'ipdt_exp_pi')}
    assert dead_times['ipdt_mdp_pid_deadtime_plus20'] == [4.8, 7.2]    # ±20 % of its 6 s
    assert dead_times['ipdt_exp_pi'] == [4.0, 6.0]                      # ±20 % of its 5 s
    assert len({c.key for c in all_cases}) == len(all_cases)


# --------------------------------------------------------------------------- one run
@pytest.mark.slow
def test_a_sweep_row_is_the_in_process_run_with_those_overrides(tmp_path):
    spec = sweep.SweepSpec(scenarios=(MDP_PID,), grid=(
        sweep.GridAxis.parse('plant.dead_time=4.0,6.5'),), duration=200.0)
    result = sweep.run_sweep(spec, tmp_path / 'sweep', sweep.InlineExecutor(), plots=False)
    for row in result.rows:
        single = runner.run(MDP_PID, tmp_path / f'run{row["run"]}', duration=200.0,
                            in_process=True, overrides=[f'plant.dead_time={row["plant.dead_time"]}'])
        expected = flat_metrics(single.metrics)
        assert {k: row[k] for k in expected} == expected
        assert row['y.overshoot_pct'] == single.metrics['outputs']['y']['steps'][0][
            'overshoot_pct']
        assert row['loop.phase_margin'] == pytest.approx(
            next(v for k, v in single.metrics['loop_analysis'].items()
                 if k.startswith('plant'))['phase_margin'], abs=0)
        with np.load(tmp_path / 'sweep' / 'traces' / f'{row["key"]}.npz') as data:
            names = list(data['names'])
            y = data['data'][:, names.index('y.y')]
        np.testing.assert_allclose(y, single.trace.columns['y.y'], rtol=1e-6, atol=1e-7)


def test_failures_are_rows_with_their_reason_and_never_stop_the_sweep(tmp_path):
    spec = sweep.SweepSpec(scenarios=(MDP_PID,), grid=(
        sweep.GridAxis.parse('plant.dead_time=-1.0,5.0'),
        sweep.GridAxis.parse('controller.sample_time=0.1,0.15')), duration=50.0)
    result = sweep.run_sweep(spec, tmp_path, sweep.InlineExecutor(), plots=False)
    by = {(r['plant.dead_time'], r['controller.sample_time']): r for r in result.rows}
    assert by[(5.0, 0.1)]['status'] == 'ok'
    bad_dead_time = by[(-1.0, 0.1)]
    assert bad_dead_time['status'] == 'failed' and 'dead_time' in bad_dead_time['reason']
    not_multiple = by[(5.0, 0.15)]
    assert not_multiple['status'] == 'failed'
    assert 'not a positive integer multiple' in not_multiple['reason']
    assert result.summary['scenarios']['ipdt_mdp_pid_deadtime_plus20']['failed'] == 3


# --------------------------------------------------------------------------- executors
@pytest.mark.slow
def test_results_do_not_depend_on_the_executor_or_the_number_of_workers(tmp_path):
    from distributed import LocalCluster
    spec = small_spec(samples=1, duration=60.0)      # 8 runs over 2 workers
    inline = sweep.run_sweep(spec, tmp_path / 'inline', sweep.InlineExecutor(), plots=False)
    with sweep.local_executor(2) as pool:
        local = sweep.run_sweep(spec, tmp_path / 'local', pool, plots=False)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster:
        executor, close = sweep.dask_executor(cluster.scheduler_address)
        try:
            dask = sweep.run_sweep(spec, tmp_path / 'dask', executor, plots=False)
        finally:
            close()
    assert all(row['status'] == 'ok' for row in inline.rows)
    reference = metric_table(inline.rows)
    assert metric_table(local.rows) == reference          # bit-identical: == on floats
    assert metric_table(dask.rows) == reference
    assert (tmp_path / 'dask' / 'results.csv').read_text() != ''
    inline_csv = [{k: v for k, v in r.items() if k != 'wall_s'}
                  for r in csv.DictReader((tmp_path / 'inline' / 'results.csv').open())]
    dask_csv = [{k: v for k, v in r.items() if k != 'wall_s'}
                for r in csv.DictReader((tmp_path / 'dask' / 'results.csv').open())]
    assert inline_csv == dask_csv


@pytest.mark.slow
def test_the_command_runs_a_study_on_a_dask_cluster(tmp_path, capsys):
    from distributed import LocalCluster
    study = tmp_path / 'study.yaml'
    study.write_text(f"""study:
  title: "dead time and gain"
  claim: "stays stable"
  scenarios: [{EXP_PI}]
  set: ["harness.duration=100.0"]
  grid:
    plant.dead_time: "±20%:3"
    plant.gain: [0.045, 0.055]
""")
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster:
        code = cli.main(['sweep', str(study), '--out', str(tmp_path / 'out'), '--quiet',
                         '--cluster', cluster.scheduler_address])
        out = capsys.readouterr().out
        scheduler_file = tmp_path / 'scheduler.json'      # what `dask scheduler` writes
        scheduler_file.write_text(json.dumps({'address': cluster.scheduler_address}))
        again = cli.main(['sweep', str(study), '--out', str(tmp_path / 'again'), '--quiet',
                          '--scheduler-file', str(scheduler_file), '--no-plots'])
    assert again == 0
    assert (tmp_path / 'again' / 'summary.json').exists()
    assert not list((tmp_path / 'again').glob('*.png'))            # --no-plots
    assert '6 runs: 6 ok, 0 failed (6 ran now' in capsys.readouterr().out
    assert code == 0
    assert '6 runs: 6 ok, 0 failed' in out
    assert '| ipdt_exp_pi | y.overshoot_pct | 6 |' in out
    import pyarrow.parquet as pq
    table = pq.read_table(tmp_path / 'out' / 'results.parquet').to_pylist()
    rows = list(csv.DictReader((tmp_path / 'out' / 'results.csv').open()))
    assert len(table) == len(rows) == 6
    for parquet_row, csv_row in zip(table, rows):
        assert float(csv_row['y.iae']) == parquet_row['y.iae']
        assert float(csv_row['plant.dead_time']) == parquet_row['plant.dead_time']
    assert sorted({r['plant.dead_time'] for r in table}) == [4.0, 5.0, 6.0]
    for name in ('envelope.png', 'metrics.png', 'heatmap.png', 'summary.md', 'summary.json'):
        assert (tmp_path / 'out' / name).stat().st_size > 0
    summary = json.loads((tmp_path / 'out' / 'summary.json').read_text())
    overshoot = summary['scenarios']['ipdt_exp_pi']['metrics']['y.overshoot_pct']
    assert overshoot['worst'] == max(r['y.overshoot_pct'] for r in table)
    worst = max(table, key=lambda r: r['y.overshoot_pct'])
    assert overshoot['worst_at'] == {'plant.dead_time': worst['plant.dead_time'],
                                     'plant.gain': worst['plant.gain']}


def test_cli_refuses_a_bad_sweep_with_one_line(tmp_path, capsys):
    code = cli.main(['sweep', str(MDP_PID), '--out', str(tmp_path), '--grid',
                     'plant.gian=1,2'])
    err = capsys.readouterr().err
    assert code == 2 and 'did you mean gain' in err and 'Traceback' not in err


# --------------------------------------------------------------------------- resume
@pytest.mark.slow
def test_a_rerun_skips_finished_runs_and_resumes_lost_ones(tmp_path):
    spec = sweep.SweepSpec(scenarios=(EXP_PI,), grid=(
        sweep.GridAxis.parse('plant.dead_time=±20%:4'),), duration=60.0)
    first = sweep.run_sweep(spec, tmp_path, sweep.InlineExecutor(), plots=False)
    assert first.ran == 4 and first.skipped == 0
    again = sweep.run_sweep(spec, tmp_path, sweep.InlineExecutor(), plots=False)
    assert again.ran == 0 and again.skipped == 4
    assert metric_table(again.rows) == metric_table(first.rows)
    # an interrupted sweep: the log lost its last two runs (one line torn mid-write)
    log = tmp_path / 'runs.jsonl'
    lines = log.read_text().splitlines()
    log.write_text('\n'.join(lines[:2]) + '\n' + lines[2][:25])
    resumed = sweep.run_sweep(spec, tmp_path, sweep.InlineExecutor(), plots=False)
    assert resumed.ran == 2 and resumed.skipped == 2
    assert metric_table(resumed.rows) == metric_table(first.rows)
    # a wider sweep reuses what it has
    wider = sweep.SweepSpec(scenarios=(EXP_PI,), grid=(
        sweep.GridAxis.parse('plant.dead_time=±20%:4'),
        sweep.GridAxis.parse('plant.gain=0.05,0.06')), duration=60.0)
    result = sweep.run_sweep(wider, tmp_path, sweep.InlineExecutor(), plots=False)
    assert result.ran == 4 and result.skipped == 4


def test_a_diverging_run_is_kept_with_its_numbers(tmp_path):
    spec = sweep.SweepSpec(scenarios=(EXP_PI,), grid=(
        sweep.GridAxis.parse('plant.gain=0.05,0.5'),), duration=300.0)
    result = sweep.run_sweep(spec, tmp_path, sweep.InlineExecutor(), plots=False)
    unstable = next(r for r in result.rows if r['plant.gain'] == 0.5)
    assert unstable['status'] == 'ok' and unstable['loop.stable'] == 0.0
    assert unstable['y.settling_time'] == math.inf
    summary = result.summary['scenarios']['ipdt_exp_pi']['metrics']
    assert summary['loop.stable']['worst'] == 0.0
    assert summary['loop.stable']['worst_at'] == {'plant.gain': 0.5}


# --------------------------------------------------------------------------- lockstep over ROS
@pytest.mark.ros
def test_lockstep_runs_in_their_own_domains_equal_the_in_process_runs(tmp_path):
    spec = sweep.SweepSpec(scenarios=(MDP_PID,), grid=(
        sweep.GridAxis.parse('plant.dead_time=4.0,6.0'),), duration=60.0)
    in_process = sweep.run_sweep(spec, tmp_path / 'inproc', sweep.InlineExecutor(), plots=False)
    ros_spec = sweep.SweepSpec(**{**spec.__dict__, 'ros': True})
    with sweep.local_executor(2) as pool:                   # two graphs at once
        ros = sweep.run_sweep(ros_spec, tmp_path / 'ros', pool, plots=False)
    assert [r['status'] for r in ros.rows] == ['ok', 'ok'], [r['reason'] for r in ros.rows]
    for a, b in zip(in_process.rows, ros.rows):
        for name in sweep.metric_columns(in_process.rows):
            if isinstance(a[name], float) and math.isfinite(a[name]):
                assert b[name] == pytest.approx(a[name], rel=1e-9, abs=1e-9), name
            else:
                assert b[name] == a[name]


# --------------------------------------------------------------------------- shipped studies
@pytest.mark.parametrize('name, runs', [('000_robustness.yaml', 4 * 9 * 7),
                                        ('tank_disturbances.yaml', 4 * 20)])
def test_shipped_studies_are_valid_and_as_documented(name, runs):
    path = CONFIG / 'studies' / name
    assert sweep.is_study(path) and not sweep.is_study(MDP_PID)
    spec = sweep.load_study(path)
    all_cases = sweep.cases(spec)
    assert len(all_cases) == runs and not [c.error for c in all_cases if c.error]
    docs = (CONFIG.parent / 'docs' / 'sweeps.md').read_text()
    assert f'config/studies/{name}' in docs


def test_study_keys_are_checked(tmp_path):
    path = tmp_path / 'bad_study.yaml'
    path.write_text(f'study:\n  scenarios: [{MDP_PID}]\n  gird: {{}}\n')
    with pytest.raises(ScenarioError, match='did you mean grid'):
        sweep.load_study(path)


def test_progress_bar_counts_runs_and_prints_a_line_per_tenth_in_a_pipe():
    import io
    stream = io.StringIO()
    bar = sweep.ProgressBar(stream, tty=False)
    for done in range(0, 21):
        bar(sweep.SweepProgress(done=done, total=20, failed=done // 10, skipped=0,
                                elapsed=done * 0.5))
    lines = stream.getvalue().splitlines()
    assert len(lines) == 11                            # 0 %, 10 %, ..., 100 %
    assert lines[-1].startswith('sweep [####################] 20/20 runs, 2 failed, 2.0 runs/s')
    assert 'ETA 5 s' in lines[5]                       # 10 of 20 done in 5 s
