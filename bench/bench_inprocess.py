"""In-process closed loop (``core/loop.py``) ticks per second, optionally against another tree.

Each tree runs in a worker process of its own (this tree: this interpreter; the baseline: the
same interpreter with ``PYTHONPATH=--baseline-path``, or ``--baseline PYTHON``, a python whose
``tank_control`` is another tree). A worker imports everything and warms each scenario up with a
short run first. A measured run builds the scenario's objects (``core.scenario.build``, not
timed) and times ``core.scenario.run`` over the scenario's ``harness.duration`` (or
``--duration``), repeated (fresh objects each time) until ``--min-time`` seconds were timed, and
reports all ticks over all timed seconds: a short scenario is not one 50 ms sample of a shared
machine. Runs alternate between the trees, so both see the same machine load.

    .venv/bin/python bench/bench_inprocess.py [--runs 5] [--all] [--baseline-path DIR]
                                              [--baseline OTHER_PYTHON] [--duration S]
                                              [--min-time 0.5] [--only FILE ...]

Prints one line per measurement and two markdown tables, ticks per wall-clock second and ticks
per CPU second of the worker (``time.process_time``: less sensitive to other processes on a
shared machine): median (min–max) per scenario, and with a baseline the ratio of the medians;
the load average before and after.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
WARMUP_SECONDS = 20.0       # simulated seconds of the warm-up run of each scenario

#: (label, scenario file relative to config/) measured by default
SCENARIOS = (
    ('IPDT PID', 'ipdt_pid.yaml'),
    ('IPDT MDP PI', 'scenarios/ipdt_mdp_pi.yaml'),
    ('FOPDT ZN ramp', 'fopdt_zn_ramp.yaml'),
    ('FOPDT relay autotune', 'scenarios/fopdt_autotune_scheduled.yaml'),
    ('tank two-loop PI', 'scenarios/tank_pi.yaml'),
    ('tank two-loop PI decoupled', 'scenarios/tank_pi_decoupled.yaml'),
    ('tank MPCS analytic', 'scenarios/tank_mpcs_analytic.yaml'),
    ('tank MPCS-QP', 'scenarios/tank_mpcs_qp.yaml'),
)


def all_scenarios() -> tuple[tuple[str, str], ...]:
    files = sorted((REPO / 'config').glob('*.yaml')) + sorted(
        (REPO / 'config' / 'scenarios').glob('*.yaml'))
    return tuple((f.stem, str(f.relative_to(REPO / 'config'))) for f in files)


# ------------------------------------------------------------------------- worker (child)
def worker() -> int:
    """Answer one JSON line per request ``{"file", "duration", "min_time"}`` with ``{"ticks",
    "seconds", "where"}``; the first request of a file warms it up first."""
    import tank_control
    from tank_control.core import scenario

    warm: set[str] = set()
    for line in sys.stdin:
        request = json.loads(line)
        sections = scenario.sections_of(request['file'])
        duration = scenario.duration_of(sections, request.get('duration'))
        if request['file'] not in warm:
            scenario.run(scenario.build(sections), min(duration, WARMUP_SECONDS))
            warm.add(request['file'])
        ticks, elapsed, cpu = 0, 0.0, 0.0
        while elapsed < request.get('min_time', 0.0) or not ticks:
            built = scenario.build(sections)
            start, start_cpu = time.perf_counter(), time.process_time()
            trace = scenario.run(built, duration)
            elapsed += time.perf_counter() - start
            cpu += time.process_time() - start_cpu
            ticks += len(trace)
        print(json.dumps({'ticks': ticks, 'seconds': elapsed, 'cpu_seconds': cpu,
                          'where': str(Path(tank_control.__file__).parent)}), flush=True)
    return 0


class Worker:
    def __init__(self, label: str, python: str, pythonpath: str | None) -> None:
        env = dict(os.environ)
        if pythonpath:
            env['PYTHONPATH'] = pythonpath
        else:
            env.pop('PYTHONPATH', None)
        self.label = label
        self.proc = subprocess.Popen([python, str(Path(__file__).resolve()), '--worker'],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                                     env=env, cwd='/')
        self.where = ''

    def measure(self, file: Path, duration: float | None, min_time: float
                ) -> tuple[float, float]:
        """(ticks per wall second, ticks per CPU second of the worker)."""
        assert self.proc.stdin and self.proc.stdout
        self.proc.stdin.write(json.dumps({'file': str(file), 'duration': duration,
                                          'min_time': min_time}) + '\n')
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError(f'{self.label} worker ended (exit {self.proc.wait()})')
        answer = json.loads(line)
        self.where = answer['where']
        return answer['ticks'] / answer['seconds'], answer['ticks'] / answer['cpu_seconds']

    def close(self) -> None:
        if self.proc.stdin:
            self.proc.stdin.close()
        self.proc.wait()


def summary(values: list[float]) -> str:
    return f'{statistics.median(values):,.0f} ({min(values):,.0f}–{max(values):,.0f})'


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--runs', type=int, default=5)
    parser.add_argument('--all', action='store_true', help='every shipped scenario')
    parser.add_argument('--only', nargs='*', help='scenario files (relative to config/)')
    parser.add_argument('--duration', type=float, help='simulated seconds (default: the file\'s)')
    parser.add_argument('--min-time', type=float, default=0.5,
                        help='timed seconds per run at least (repeats of the scenario)')
    parser.add_argument('--baseline-path', help='source tree of the baseline (PYTHONPATH)')
    parser.add_argument('--baseline', help='a python whose tank_control is the baseline')
    parser.add_argument('--worker', action='store_true', help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        return worker()
    scenarios = all_scenarios() if args.all else SCENARIOS
    if args.only:
        scenarios = tuple((Path(f).stem, f) for f in args.only)
    workers = [Worker('this tree', sys.executable, str(REPO))]
    if args.baseline_path or args.baseline:
        workers.append(Worker('baseline', args.baseline or sys.executable, args.baseline_path))
    load_before = os.getloadavg()
    results: dict[tuple[str, str], list[float]] = {}
    per_cpu: dict[tuple[str, str], list[float]] = {}
    try:
        for run in range(args.runs):
            for label, rel in scenarios:
                for w in workers:
                    rate, cpu_rate = w.measure(REPO / 'config' / rel, args.duration,
                                               args.min_time)
                    results.setdefault((label, w.label), []).append(rate)
                    per_cpu.setdefault((label, w.label), []).append(cpu_rate)
                    print(f'run {run + 1}: {label:28s} {w.label:9s} {rate:10,.0f} ticks/s '
                          f'{cpu_rate:10,.0f} ticks/CPU-s', flush=True)
    finally:
        for w in workers:
            w.close()
    load_after = os.getloadavg()
    print()
    for w in workers:
        print(f'{w.label}: tank_control from {w.where}')
    print(f'load average before {load_before[0]:.2f} {load_before[1]:.2f} {load_before[2]:.2f}, '
          f'after {load_after[0]:.2f} {load_after[1]:.2f} {load_after[2]:.2f}; '
          f'{os.cpu_count()} CPUs; median of {args.runs} runs of >= {args.min_time:g} s each')
    print()
    for title, table in (('ticks per wall-clock second', results),
                         ('ticks per CPU second of the worker process', per_cpu)):
        print(f'{title}:')
        print()
        head = '| scenario | this tree |'
        if len(workers) > 1:
            head += ' baseline | ratio |'
        print(head)
        print('|' + '---|' * (head.count('|') - 1))
        for label, _ in scenarios:
            mine = table[(label, 'this tree')]
            row = f'| {label} | {summary(mine)} |'
            if len(workers) > 1:
                base = table[(label, 'baseline')]
                row += (f' {summary(base)} | '
                        f'{statistics.median(mine) / statistics.median(base):.2f} |')
            print(row)
        print()
    return 0


if __name__ == '__main__':
    sys.exit(main())
