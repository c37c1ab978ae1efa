"""``tank-control``: run and compare scenarios.

    tank-control list [--dir DIR]
    tank-control run SCENARIO.yaml --out DIR [--mode lockstep|sim|wall] [--rtf X]
                     [--duration S] [--set NODE.PARAM=VALUE ...] [--in-process] [--no-plots]
    tank-control compare A.yaml B.yaml ... --out DIR [same options]
    tank-control analyze SCENARIO.yaml [--set NODE.PARAM=VALUE ...]
    tank-control assess FILE.csv --pv COL --sp COL --op COL --sample-time S [--dead-time L]
                     [--time COL] [--op-limits LO HI] [--manual COL] [--plot PNG] [--json]
    tank-control recover OUT [--force]
    tank-control sweep SCENARIO.yaml ... | STUDY.yaml --out DIR [--grid NODE.PARAM=SPEC ...]
                     [--random NODE.PARAM=DIST ...] [--samples N] [--seed S] [--set ...]
                     [--duration S] [--workers N | --cluster ADDRESS | --scheduler-file F]
                     [--ros] [--no-plots]

Exit status: 0 done (a sweep: some runs succeeded), 1 the run failed (a node crashed, did not
start or stalled: its last log lines are printed; another run or graph on the ROS_DOMAIN_ID;
nothing recorded), 2 bad command line or scenario (recover: not a run's directory, a run still
writing it, or its results already written), 128 + N stopped by signal N (130 SIGINT,
143 SIGTERM, 129 SIGHUP). A failed or stopped run leaves what it recorded, with
``"complete": false`` and the reason in metrics.json.
"""
from __future__ import annotations

import argparse
import atexit
import gc
import math
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TextIO

from tank_control import cli_examples
from tank_control.harness.scenario_file import CLOCK_MODES, ScenarioError


class ProgressPrinter:
    """A rewritten status line on a terminal; a plain line per 10 % in CI or a pipe."""

    def __init__(self, stream: TextIO, label: str, tty: bool | None = None) -> None:
        self.stream = stream
        self.label = label
        self.tty = (stream.isatty() and not os.environ.get('CI')) if tty is None else tty
        self._last_decile = -1

    def __call__(self, p) -> None:
        eta = '?' if not math.isfinite(p.eta) else f'{p.eta:.0f} s'
        text = (f'{self.label}: sim {p.sim_time:.1f}/{p.duration:g} s, '
                f'{p.rate:.1f}x real time, {p.ticks_per_s:.0f} ticks/s, ETA {eta}')
        if self.tty:
            self.stream.write('\r' + text.ljust(100))
            if p.sim_time >= p.duration:
                self.stream.write('\n')
        else:
            decile = int(10 * p.sim_time / p.duration) if p.duration > 0 else 10
            if decile == self._last_decile:
                return
            self._last_decile = decile
            self.stream.write(text + '\n')
        self.stream.flush()


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog='tank-control', description=__doc__.split('\n\n')[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest='command', required=True)

    def options(p: argparse.ArgumentParser) -> None:
        p.add_argument('--out', required=True, type=Path, help='output directory')
        p.add_argument('--mode', choices=CLOCK_MODES, help='clock mode (overrides the file)')
        p.add_argument('--rtf', type=float, help='real-time factor (0 = as fast as possible)')
        p.add_argument('--duration', type=float, help='simulated seconds to run')
        p.add_argument('--set', dest='overrides', action='append', default=[],
                       metavar='NODE.PARAM=VALUE', help='override a parameter (typed as YAML)')
        p.add_argument('--in-process', action='store_true',
                       help='run core/loop.py without ROS (same files written)')
        p.add_argument('--quiet', action='store_true', help='no progress output')
        p.add_argument('--no-plots', dest='plots', action='store_false',
                       help='write no plot.png and analysis.png (batch runs: the trace, '
                            'recording and metrics are the same)')

    listing = sub.add_parser('list', help='the shipped scenarios and studies with their titles')
    listing.add_argument('--dir', type=Path, help='list this folder instead (recursively)')
    listing.add_argument('--kinds', action='store_true',
                         help='list the controller and plant kinds and where each comes from '
                              '(built-in or an installed distribution; docs/extending.md)')
    run = sub.add_parser('run', help='run one scenario')
    run.add_argument('scenario', type=Path)
    options(run)
    run.add_argument('--dashboard', nargs='?', type=int, const=8080, metavar='PORT',
                     help='watch the run in a web page: start dashboard_node on PORT '
                          '(default 8080) for the run (docs/dashboard.md)')
    compare = sub.add_parser('compare', help='run several scenarios and compare their metrics')
    compare.add_argument('scenarios', type=Path, nargs='+')
    options(compare)
    analyze = sub.add_parser('analyze', help="robustness of a scenario's SISO loop on its plant "
                             'model (stability, GM, PM, Ms, Mt, delay margin), without running')
    analyze.add_argument('scenario', type=Path)
    analyze.add_argument('--set', dest='overrides', action='append', default=[],
                         metavar='NODE.PARAM=VALUE', help='override a parameter (typed as YAML)')
    analyze.add_argument('--plot', type=Path, metavar='OUT.png',
                         help='also draw Bode (margins marked), Nyquist (Ms circle) and the '
                              'gang of four (SISO) or each loop with the other closed (two-loop)')
    analyze.add_argument('--json', action='store_true', help='print the numbers as JSON')
    assess = sub.add_parser('assess', help='control performance of one loop recorded in a CSV '
                            '(Harris index, oscillation, stiction, saturation; a verdict and a '
                            'plot: docs/monitoring.md)')
    assess.add_argument('csv', type=Path, help='a CSV file with a header row')
    assess.add_argument('--pv', required=True, help='column of the process value (measurement)')
    assess.add_argument('--sp', required=True, help='column of the setpoint')
    assess.add_argument('--op', required=True, help='column of the controller output')
    assess.add_argument('--sample-time', required=True, type=float, help='[s] between rows')
    assess.add_argument('--dead-time', type=float, default=0.0,
                        help='[s] of the loop (Harris index; default 0: one sample)')
    assess.add_argument('--time', dest='time_column', help='column of the time [s] (default: '
                        'row number x sample time)')
    assess.add_argument('--op-limits', type=float, nargs=2, metavar=('LO', 'HI'),
                        help='the controller output limits (saturation time)')
    assess.add_argument('--manual', help='column that is non-zero while the loop is in manual')
    assess.add_argument('--plot', type=Path, help='the plot (default: FILE.assess.png)')
    assess.add_argument('--json', action='store_true',
                        help='print every index and the plot\'s path as one JSON document '
                             'instead of the text')
    recover = sub.add_parser('recover', help='rebuild run.mcap (indexed), trace.csv and '
                             'metrics.json of a run whose harness was killed (docs/harness.md)')
    recover.add_argument('out', type=Path, help="the run's output directory")
    recover.add_argument('--force', action='store_true',
                         help='also when metrics.json is there (rebuild from run.mcap)')
    sweep = sub.add_parser('sweep', help='many runs: grids and Monte Carlo over parameters '
                           '(docs/sweeps.md)')
    sweep.add_argument('scenarios', type=Path, nargs='+',
                       help='scenario files, or one study file (config/studies/)')
    sweep.add_argument('--out', required=True, type=Path, help='output directory (rerun: resume)')
    sweep.add_argument('--grid', action='append', default=[], metavar='NODE.PARAM=SPEC',
                       help='v1,v2,... or a:b:n or ±p%%:n (around the scenario\'s value); '
                       'NODE.PARAM[i] for element i of a list')
    sweep.add_argument('--random', action='append', default=[], metavar='NODE.PARAM=DIST',
                       help='normal(mu,sigma), uniform(a,b) or randint(a,b)')
    sweep.add_argument('--samples', type=int, help='random draws per grid point')
    sweep.add_argument('--seed', type=int, help='seed of the random draws (default 0)')
    sweep.add_argument('--set', dest='overrides', action='append', default=[],
                       metavar='NODE.PARAM=VALUE', help='a fixed override for every run')
    sweep.add_argument('--duration', type=float, help='simulated seconds per run')
    where = sweep.add_mutually_exclusive_group()
    where.add_argument('--workers', type=int, help='local worker processes (default: all cores)')
    where.add_argument('--cluster', metavar='ADDRESS',
                       help='run on a dask.distributed scheduler (tcp://HOST:PORT)')
    where.add_argument('--scheduler-file', metavar='FILE', help='Dask scheduler file')
    sweep.add_argument('--ros', action='store_true',
                       help='each run in lockstep over ROS 2, in a ROS_DOMAIN_ID of its own')
    sweep.add_argument('--quiet', action='store_true', help='no progress bar')
    sweep.add_argument('--no-plots', dest='plots', action='store_false',
                       help='write the table and summary only (no envelope or metrics plots)')
    return cli_examples.attach(parser)


def _list(directory: Path | None) -> int:
    """Print ``path  title`` per scenario (paths relative to the working directory when
    below it, so they can be pasted into ``tank-control run``)."""
    from tank_control.harness.scenario_file import list_scenarios, shipped_config_dir
    directory = shipped_config_dir() if directory is None else directory
    if not directory.is_dir():
        print(f'tank-control: {directory}: not a directory', file=sys.stderr)
        return 2
    rows = []
    for path, title in list_scenarios(directory):
        try:
            path = path.resolve().relative_to(Path.cwd().resolve())
        except ValueError:
            pass
        rows.append((str(path), title))
    width = max((len(p) for p, _ in rows), default=0)
    for path, title in rows:
        print(f'{path.ljust(width)}  {title}'.rstrip())
    return 0


def _sweep(args: argparse.Namespace) -> int:
    from tank_control.harness import sweep
    if len(args.scenarios) == 1 and sweep.is_study(args.scenarios[0]):
        spec = sweep.load_study(args.scenarios[0])
    else:
        spec = sweep.SweepSpec(scenarios=tuple(args.scenarios))
    spec = sweep.SweepSpec(
        scenarios=spec.scenarios,
        grid=spec.grid + tuple(sweep.GridAxis.parse(g) for g in args.grid),
        random=spec.random + tuple(sweep.RandomAxis.parse(r) for r in args.random),
        samples=spec.samples if args.samples is None else args.samples,
        seed=spec.seed if args.seed is None else args.seed,
        sets=spec.sets + tuple(args.overrides),
        duration=spec.duration if args.duration is None else args.duration,
        ros=spec.ros or args.ros, title=spec.title, claim=spec.claim)
    sweep.cases(spec)                         # every bad specification before anything starts
    close = None
    if args.cluster or args.scheduler_file:
        executor, close = sweep.dask_executor(args.cluster, args.scheduler_file)
    else:
        executor = sweep.local_executor(args.workers)
    progress = None if args.quiet else sweep.ProgressBar(sys.stderr)
    try:
        result = sweep.run_sweep(spec, args.out, executor, progress, plots=args.plots)
    except KeyboardInterrupt:
        print(f'tank-control: sweep interrupted; finished runs are kept in {args.out}/runs.jsonl '
              '(rerun the same command to resume)', file=sys.stderr)
        return 130
    finally:
        executor.shutdown(wait=False)
        if close:
            close()
    print(sweep.summary_markdown(result.summary), end='')
    ok = sum(row['status'] == 'ok' for row in result.rows)
    print(f'{len(result.rows)} runs: {ok} ok, {len(result.rows) - ok} failed '
          f'({result.ran} ran now, {result.skipped} from an earlier invocation)')
    for key, path in result.files.items():
        print(f'{key}: {path}')
    return 0 if ok else 1


def _run_one(path: Path, out: Path, args: argparse.Namespace):
    from tank_control.harness import runner
    progress = None if args.quiet else ProgressPrinter(sys.stderr, path.stem)
    dashboard = getattr(args, 'dashboard', None)
    if dashboard is not None and not args.in_process:
        from tank_control.dashboard.access import TOKEN_ENV, new_token
        token = os.environ.setdefault(TOKEN_ENV, new_token())    # dashboard_node takes it
        print(f'dashboard: http://127.0.0.1:{dashboard}/?token={token} (until the run ends)',
              file=sys.stderr)
    return runner.run(path, out, mode=args.mode, rtf=args.rtf, duration=args.duration,
                      overrides=args.overrides, in_process=args.in_process, progress=progress,
                      dashboard=dashboard, plots=args.plots)


def _print_result(result) -> None:
    from tank_control.harness.compare import markdown_table
    claim = result.metrics.get('claim')
    if claim:
        print(f'documented claim: {claim}')
    print(markdown_table([result]), end='')
    summary = result.metrics.get('controller', {}).get('summary')
    if summary:
        print(f'controller found: {summary}')
    for warning in result.metrics.get('controller', {}).get('warnings', []):
        print(f'controller warning: {warning}')
    for key in ('plot', 'analysis', 'trace', 'recording', 'metrics'):
        if key in result.files:
            print(f'{key}: {result.files[key]}')
    for line in run_warnings(result.metrics):
        print(f'tank-control: warning: {line}', file=sys.stderr)


def run_warnings(metrics: dict) -> list[str]:
    """What a user must know of a run that completed: nodes restarted, nodes on the domain
    that the harness did not start (``run.restarts``, ``run.foreign_nodes``)."""
    run = metrics.get('run', {})
    lines = []
    for r in run.get('restarts', []):
        at = f' at {r["time"]:g} s' if r.get('time') is not None else ''
        lines.append(f'node {r["node"]} exited with code {r["exit_code"]}{at} and was restarted '
                     f'(restart {r["attempt"]} of this node; harness.on_node_exit restart)')
    foreign = run.get('foreign_nodes', [])
    if foreign:
        seen = ', '.join(f'{n["node"]} ({n["first_seen"]:g}–{n["last_seen"]:g} s)' for n in foreign)
        lines.append(f'nodes the harness did not start were on its ROS_DOMAIN_ID during the run: '
                     f'{seen}; they could publish into the loop or change parameters')
    return lines


def _assess(args: argparse.Namespace) -> int:
    """``tank-control assess``: the verdict on stdout, the plot written; 2 for a bad file or
    column (one line naming it)."""
    import json

    from tank_control.harness.performance import AssessError, assess_csv, plot_assessment
    limits = tuple(args.op_limits) if args.op_limits else (-math.inf, math.inf)
    try:
        body, columns = assess_csv(args.csv, args.pv, args.sp, args.op, args.sample_time,
                                   args.dead_time, args.time_column, limits, args.manual)
    except AssessError as err:
        print(f'tank-control: {err}', file=sys.stderr)
        return 2
    plot = args.plot or args.csv.with_suffix('.assess.png')
    plot_assessment(columns, body, plot, title=f'{args.csv.name} {args.pv}')
    if args.json:                       # the JSON alone: stdout parses as one document
        print(json.dumps({**body, 'plot': str(plot)}, indent=1))
        return 0
    harris = body['harris_index']
    print(f'{args.pv}: {body["verdict"]}')
    print(f'  Harris index {harris:.2f} (dead time {body["dead_time_samples"]} samples)'
          if harris is not None else f'  Harris index: none ({body["harris_reason"]})')
    osc = body['oscillation']
    if osc['detected']:
        print(f'  oscillation: period {osc["period"]:.3g} s, amplitude {osc["amplitude"]:.3g}, '
              f'regularity {osc["regularity"]:.2f}')
    if body['stiction']['index'] is not None:
        print(f'  stiction index {body["stiction"]["index"]:.2f} (Horch cross-correlation)')
    if body['saturation_pct'] is not None:
        print(f'  saturated {body["saturation_pct"]:.1f} % of the time')
    print(f'plot: {plot}')
    return 0


def _recover(out: Path, force: bool) -> int:
    from tank_control.harness.recover import RecoverError, recover
    from tank_control.harness.scenario_file import ScenarioError
    try:
        result, found = recover(out, force)
    except (RecoverError, ScenarioError) as err:
        print(f'tank-control: {err}', file=sys.stderr)
        return 2
    info = result.metrics['run']['recovered']
    last = info['last_measurement']
    print(f'{out}: recovered {info["messages"]} messages of run.mcap'
          + (f' (last measurement at {last:g} s of plant time)' if last is not None else '')
          + (f'; dropped {info["bytes_dropped"]} bytes at its end ({found.stopped})'
             if info['bytes_dropped'] else '')
          + (f'; skipped {info["bad_chunks"]} damaged chunks' if info['bad_chunks'] else ''))
    print(f'trace.csv: {result.metrics["run"]["ticks"]} rows; metrics.json: "complete": false')
    for key in ('plot', 'analysis', 'trace', 'recording', 'metrics'):
        if key in result.files:
            print(f'{key}: {result.files[key]}')
    return 0


def _partial(err: BaseException) -> str:
    """Where a failed or stopped run left what it recorded (nothing if it wrote nothing)."""
    out = getattr(err, 'partial_results', None)
    return f'\nthe results so far are in {out} ("complete": false)' if out else ''


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    if argv is None:
        # The process ends with the command: what it made needs no collection at the
        # interpreter's shutdown (a run's objects: 0.3 s of the command's exit).
        atexit.register(gc.freeze)
    if argv is None and 'rclpy' not in sys.modules:
        # The command's own participant (the recorder) announces itself at start like the
        # nodes it starts (domains.START_ANNOUNCEMENTS); Fast DDS reads the variable once,
        # when rclpy is first imported. Not for main(argv) called inside another program.
        from tank_control.harness.domains import start_profile_env
        os.environ.update(start_profile_env(os.environ))
    from tank_control.harness.runner import RunFailed, RunInterrupted
    if args.command == 'list' and args.kinds:
        from tank_control.harness.kinds_list import kinds_listing
        print(kinds_listing(), end='')
        return 0
    if args.command == 'list':
        return _list(args.dir)
    if args.command == 'recover':
        return _recover(args.out, args.force)
    if args.command == 'assess':
        return _assess(args)
    try:
        if args.command == 'run':
            _print_result(_run_one(args.scenario, args.out, args))
            return 0
        if args.command == 'sweep':
            return _sweep(args)
        if args.command == 'analyze':
            from tank_control.harness.analysis import analyze
            print(analyze(args.scenario, tuple(args.overrides), plot=args.plot,
                          as_json=args.json), end='')
            return 0
        from tank_control.harness.compare import write_comparison
        results, used = [], set()
        for path in args.scenarios:
            name = path.stem
            while name in used:
                name += '_'
            used.add(name)
            results.append(_run_one(path, args.out / name, args))
        files = write_comparison(results, args.out, plots=args.plots)
        print(files['table'].read_text(), end='')
        for result in results:
            for warning in result.metrics.get('controller', {}).get('warnings', []):
                print(f'{result.name}: controller warning: {warning}')
        print('\n'.join(f'{key}: {path}' for key, path in files.items()))
        return 0
    except ScenarioError as err:
        print(f'tank-control: {err}', file=sys.stderr)
        return 2
    except RunFailed as err:
        print(f'tank-control: run failed: {err}{_partial(err)}', file=sys.stderr)
        return 1
    except RunInterrupted as stop:
        print(f'tank-control: {stop}{_partial(stop)}', file=sys.stderr)
        return stop.exit_code
    except KeyboardInterrupt:
        print('tank-control: interrupted', file=sys.stderr)
        return 130


if __name__ == '__main__':
    sys.exit(main())
