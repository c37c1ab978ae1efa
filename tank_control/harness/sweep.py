"""Sweeps and Monte Carlo studies: many runs of scenarios with overrides, on any executor.

A sweep is a set of cases: every scenario × every grid point × every random sample. Each case
is its scenario with the overrides applied, run in-process (the path of ``tank-control run
--in-process``: ``runner.simulate`` and ``runner.run_metrics``) or in lockstep over ROS 2 in a
``ROS_DOMAIN_ID`` of its own. Cases are handed to a ``concurrent.futures``-style executor
(local processes, or a ``dask.distributed`` cluster's executor), so the engine is a choice.

Specifications (docs/sweeps.md):

* grid ``NODE.PARAM=v1,v2,…`` (YAML-typed), ``a:b:n`` (n points from a to b), ``±p%:n``
  (n points from −p % to +p % around the scenario's value); ``NODE.PARAM[i]`` names element i
  of a list parameter (e.g. one value of a reference schedule);
* random ``NODE.PARAM=normal(μ,σ)``, ``uniform(a,b)``, ``randint(a,b)`` (a ≤ k ≤ b), with
  ``samples`` draws from ``numpy.random.default_rng(seed)``, drawn in order (sample by sample,
  parameter by parameter) in the parent process: the same draws for every scenario and grid
  point, whatever the executor, so results do not depend on where the runs ran.

Output in the ``--out`` directory: ``runs.jsonl`` (one line per finished run, appended as runs
finish: a rerun skips them), ``traces/<key>.npz``, ``results.csv`` and ``results.parquet``
(overrides and the metrics of every run; failed runs as rows with their reason),
``summary.json``/``summary.md`` (percentiles and the worst case), ``envelope.png`` (all responses
over time), ``metrics.png`` (each metric against each swept parameter) and, with two or more
grid parameters, ``heatmap.png``.
"""
from __future__ import annotations

import concurrent.futures as cf
import csv
import hashlib
import io
import itertools
import json
import math
import os
import re
import tempfile
import time
import traceback
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import numpy as np
import yaml

from tank_control.core import node_specs
from tank_control.core.analysis.metrics_row import flat_metrics
from tank_control.core.params import ConfigError, unknown_reason
from tank_control.core.scenario import HARNESS
from tank_control.harness.scenario_file import (Scenario, ScenarioError, effective_harness,
                                                load_scenario, parse_value, run_value,
                                                validate)

_TARGET = re.compile(r'^(?P<section>[A-Za-z_]+)\.(?P<name>[A-Za-z_][A-Za-z0-9_.]*?)'
                     r'(?:\[(?P<index>\d+)\])?$')
_RANGE = re.compile(r'^(?P<a>[^:]+):(?P<b>[^:]+):(?P<n>\d+)$')
_RELATIVE = re.compile(r'^(?:±|\+-|\+/-)(?P<p>[0-9.eE+-]+)%:(?P<n>\d+)$')
_DIST = re.compile(r'^(?P<dist>normal|uniform|randint)\((?P<a>[^,]+),(?P<b>[^,)]+)\)$')
#: metrics where a smaller value is the worse one (margins, stability)
SMALLER_IS_WORSE = ('gain_margin', 'phase_margin', 'delay_margin', 'stable', 'harris_index')
#: columns that are not results of the run's mathematics (they vary run to run)
NONDETERMINISTIC = ('wall_s',)
TABLE_FIXED = ('run', 'scenario', 'sample', 'status', 'reason')


class SweepError(ScenarioError):
    """A sweep specification that cannot be used; the message is one line."""


# ------------------------------------------------------------------------------ specification
@dataclass(frozen=True)
class Target:
    """A parameter to vary: ``section.name`` or element ``index`` of a list parameter."""

    section: str
    name: str
    index: int | None = None

    @property
    def label(self) -> str:
        return f'{self.section}.{self.name}' + ('' if self.index is None else f'[{self.index}]')

    @classmethod
    def parse(cls, text: str) -> Target:
        match = _TARGET.match(text.strip())
        if not match:
            raise SweepError(f'{text!r}: expected NODE.PARAM or NODE.PARAM[i]')
        section = match['section']
        if section not in (*node_specs.NODES, HARNESS):
            raise SweepError(f'{text!r}: ' + unknown_reason(section, (*node_specs.NODES, HARNESS),
                                                            'node'))
        index = match['index']
        return cls(section, match['name'], None if index is None else int(index))

    def current(self, scenario: Scenario) -> Any:
        """The value the scenario runs with (its file's, else the node's declared default)."""
        try:
            value = run_value(scenario, self.section, self.name)
        except ConfigError as exc:
            raise SweepError(str(exc)) from None
        if self.index is None:
            return value
        if not isinstance(value, (list, tuple)) or self.index >= len(value):
            size = len(value) if isinstance(value, (list, tuple)) else 'not a list'
            raise SweepError(f'{self.label}: {scenario.path.name} has {self.section}.{self.name} '
                             f'= {value!r} ({size}); the index must name one of its elements')
        return value[self.index]

    def apply(self, scenario: Scenario, value: Any) -> Scenario:
        if self.index is not None:
            whole = list(Target(self.section, self.name).current(scenario))
            whole[self.index] = value
            value = whole
        return scenario.with_set(self.section, self.name, value)


def _tidy(value: float) -> float:
    """A grid value to 12 significant digits (6·(1 − 0.2) is 4.8, not 4.800000000000001)."""
    return float(f'{value:.12g}')


def _number(text: str, where: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise SweepError(f'{where}: {text.strip()!r} is not a number') from None
    if not math.isfinite(value):
        raise SweepError(f'{where}: {text.strip()!r} is not a finite number')
    return value


@dataclass(frozen=True)
class GridAxis:
    """One grid parameter and its values (``v1,v2,…``, ``a:b:n`` or ``±p%:n``)."""

    target: Target
    spec: str

    @classmethod
    def parse(cls, item: str) -> GridAxis:
        key, sep, spec = item.partition('=')
        if not sep or not spec.strip():
            raise SweepError(f'--grid {item!r}: expected NODE.PARAM=v1,v2,… or a:b:n or ±p%:n')
        axis = cls(Target.parse(key), spec.strip())
        axis.values(None)            # the syntax, before any scenario is read
        return axis

    def values(self, nominal: Any) -> list[Any]:
        where = f'--grid {self.target.label}={self.spec}'
        relative = _RELATIVE.match(self.spec)
        ranged = _RANGE.match(self.spec)
        match = relative or ranged
        if match is not None:
            n = int(match['n'])
            if n < 1:
                raise SweepError(f'{where}: at least 1 point')
            if relative:
                p = _number(relative['p'], where) / 100.0
                if nominal is None:
                    return []
                if isinstance(nominal, bool) or not isinstance(nominal, (int, float)):
                    raise SweepError(f'{where}: ±% needs a number; the scenario has {nominal!r}')
                factors = np.linspace(-p, p, n) if n > 1 else np.zeros(1)
                return [_tidy(float(nominal) * (1.0 + float(f))) for f in factors]
            a, b = _number(match['a'], where), _number(match['b'], where)   # ranged
            return [_tidy(float(v)) for v in (np.linspace(a, b, n) if n > 1 else [a])]
        return [parse_value(part) for part in self.spec.split(',')]


@dataclass(frozen=True)
class RandomAxis:
    """One random parameter: ``normal(μ,σ)``, ``uniform(a,b)`` or ``randint(a,b)``."""

    target: Target
    dist: str
    a: float
    b: float

    @classmethod
    def parse(cls, item: str) -> RandomAxis:
        key, sep, spec = item.partition('=')
        match = _DIST.match(spec.replace(' ', ''))
        if not sep or not match:
            raise SweepError(f'--random {item!r}: expected NODE.PARAM=normal(mu,sigma), '
                             'uniform(a,b) or randint(a,b)')
        where = f'--random {item}'
        a, b = _number(match['a'], where), _number(match['b'], where)
        dist = match['dist']
        if dist == 'normal' and b < 0:
            raise SweepError(f'{where}: sigma must be >= 0')
        if dist in ('uniform', 'randint') and b < a:
            raise SweepError(f'{where}: needs a <= b')
        if dist == 'randint' and (a != int(a) or b != int(b)):
            raise SweepError(f'{where}: randint bounds must be integers')
        return cls(Target.parse(key), dist, a, b)

    def draw(self, rng: np.random.Generator) -> float | int:
        if self.dist == 'normal':
            return float(rng.normal(self.a, self.b))
        if self.dist == 'uniform':
            return float(rng.uniform(self.a, self.b))
        return int(rng.integers(int(self.a), int(self.b), endpoint=True))


@dataclass(frozen=True)
class SweepSpec:
    """What to run: scenarios, fixed overrides, grid and random parameters."""

    scenarios: tuple[Path, ...]
    grid: tuple[GridAxis, ...] = ()
    random: tuple[RandomAxis, ...] = ()
    samples: int = 0
    seed: int = 0
    sets: tuple[str, ...] = ()
    duration: float | None = None
    ros: bool = False
    title: str = ''
    claim: str = ''

    def reason(self) -> str | None:
        if not self.scenarios:
            return 'no scenario given'
        if self.random and self.samples < 1:
            return '--random needs --samples N (N >= 1)'
        if self.samples and not self.random:
            return '--samples needs at least one --random parameter'
        labels = [a.target.label for a in self.grid] + [a.target.label for a in self.random]
        twice = sorted({x for x in labels if labels.count(x) > 1})
        if twice:
            return f'{twice[0]} is swept twice'
        return None


STUDY_KEYS = ('title', 'claim', 'scenarios', 'set', 'grid', 'random', 'samples', 'seed',
              'duration', 'ros')


def is_study(path: Path) -> bool:
    """A study file: YAML with a top-level ``study`` map (not a ROS parameters file)."""
    try:
        data = yaml.safe_load(Path(path).read_text())
    except (OSError, yaml.YAMLError):
        return False
    return isinstance(data, dict) and set(data) == {'study'}


def load_study(path: Path) -> SweepSpec:
    """A shipped study (``config/studies/*.yaml``): scenarios relative to the file."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())['study']
    except (OSError, yaml.YAMLError, KeyError, TypeError) as exc:
        raise SweepError(f'{path}: not a study file ({exc})') from None
    if not isinstance(data, dict):
        raise SweepError(f'{path}: study: expected a map')
    for key in data:
        if key not in STUDY_KEYS:
            raise SweepError(f'{path}: study.' + unknown_reason(key, STUDY_KEYS))

    def items(key: str) -> list[str]:
        value = data.get(key) or {}
        if isinstance(value, dict):
            return [f'{k}={_spec_text(v)}' for k, v in value.items()]
        if isinstance(value, list):
            return [str(v) for v in value]
        raise SweepError(f'{path}: study.{key}: expected a map or a list')

    scenarios = data.get('scenarios') or []
    if not isinstance(scenarios, list) or not scenarios:
        raise SweepError(f'{path}: study.scenarios: expected a list of scenario files')
    try:
        return SweepSpec(
            scenarios=tuple((path.parent / str(s)).resolve() for s in scenarios),
            grid=tuple(GridAxis.parse(i) for i in items('grid')),
            random=tuple(RandomAxis.parse(i) for i in items('random')),
            samples=int(data.get('samples', 0)), seed=int(data.get('seed', 0)),
            sets=tuple(items('set')),
            duration=None if data.get('duration') is None else float(data['duration']),
            ros=bool(data.get('ros', False)),
            title=str(data.get('title', '')), claim=str(data.get('claim', '')))
    except SweepError as exc:
        raise SweepError(f'{path}: {exc}') from None


def _spec_text(value: Any) -> str:
    if isinstance(value, list):
        return ','.join(json.dumps(v) if isinstance(v, str) else str(v) for v in value)
    return str(value)


# ------------------------------------------------------------------------------ cases
@dataclass(frozen=True)
class Case:
    """One run of the sweep (``error``: the overrides are refused; nothing to run)."""

    index: int
    scenario: Scenario
    overrides: dict[str, Any]
    sample: int | None
    key: str
    ros: bool
    error: str = ''

    def payload(self) -> dict[str, Any]:
        """What a worker needs (picklable, no files): the run's sections."""
        return {'key': self.key, 'path': str(self.scenario.path),
                'sections': self.scenario.sections, 'ros': self.ros}


def _key(scenario: Scenario, ros: bool) -> str:
    text = json.dumps({'scenario': scenario.name, 'sections': scenario.sections, 'ros': ros},
                      sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def cases(spec: SweepSpec) -> list[Case]:
    """Every case of the sweep, in a fixed order (scenario, grid point, sample)."""
    reason = spec.reason()
    if reason:
        raise SweepError(reason)
    rng = np.random.default_rng(spec.seed)
    draws = [[axis.draw(rng) for axis in spec.random] for _ in range(spec.samples)]
    out: list[Case] = []
    names: dict[str, int] = {}
    for path in spec.scenarios:
        base = load_scenario(path, spec.sets)
        base = effective_harness(base, 'lockstep' if spec.ros else None, None, spec.duration)
        label = base.name
        names[label] = names.get(label, 0) + 1
        if names[label] > 1:
            label = f'{label}_{names[label]}'
        axes = [[(axis.target, v) for v in axis.values(axis.target.current(base))]
                for axis in spec.grid]
        samples: list[tuple[int | None, list[Any]]] = (
            [(i, d) for i, d in enumerate(draws)] if spec.random else [(None, [])])
        for point in itertools.product(*axes):
            for sample, values in samples:
                assigned = [*point, *zip((a.target for a in spec.random), values)]
                overrides = {target.label: value for target, value in assigned}
                scenario, error = Scenario(Path(path), base.sections), ''
                try:
                    for target, value in assigned:
                        scenario = target.apply(scenario, value)
                    scenario = validate(scenario)
                except ConfigError as exc:
                    error = str(exc).replace(f'{path}: ', '')
                scenario = Scenario(scenario.path.with_name(label + scenario.path.suffix),
                                    scenario.sections)
                out.append(Case(len(out), scenario, overrides, sample,
                                _key(scenario, spec.ros), spec.ros, error))
    return out


# ------------------------------------------------------------------------------ one run
def run_case(payload: Mapping[str, Any]) -> dict[str, Any]:
    """Run one case (in any process: a local worker, a Dask worker) and return its record.

    Never raises for a run that fails: the record has ``status`` ``failed`` and a one-line
    ``reason``; the trace, if any, as the bytes of an ``.npz`` file (``names``, float32
    ``data``).
    """
    start = time.monotonic()
    scenario = Scenario(Path(payload['path']), payload['sections'])
    record: dict[str, Any] = {'key': payload['key'], 'status': 'ok', 'reason': '',
                              'metrics': {}, 'wall_s': 0.0, 'trace_npz': None}
    try:
        if payload['ros']:
            metrics, trace = _run_ros(scenario)
        else:
            from tank_control.harness.runner import run_metrics, simulate
            trace, built = simulate(scenario)
            metrics, _ = run_metrics(scenario, trace, built.controller_values(),
                                     plant_only=True)
        record['metrics'] = flat_metrics(metrics)
        keep = [n for n in trace.names if n == 't' or n[:2] in ('y.', 'r.', 'u.', 'd.')]
        buffer = io.BytesIO()                      # compressed here, in parallel, not in the parent
        np.savez_compressed(buffer, names=np.array(keep), data=np.column_stack(
            [trace.columns[n] for n in keep]).astype(np.float32))
        record['trace_npz'] = buffer.getvalue()
    except Exception as exc:                        # noqa: BLE001  (one bad run never kills the sweep)
        record['status'] = 'failed'
        record['reason'] = _one_line(exc)
    record['wall_s'] = time.monotonic() - start
    return record


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    where = ''
    if not isinstance(exc, (ConfigError, ValueError, RuntimeError)):
        frame = traceback.extract_tb(exc.__traceback__)[-1:]
        where = f' (at {Path(frame[0].filename).name}:{frame[0].lineno})' if frame else ''
    return f'{type(exc).__name__}: {text[0] if text else ""}{where}'


def _run_ros(scenario: Scenario) -> tuple[dict[str, Any], Any]:
    """The case in lockstep over ROS 2, in a ROS_DOMAIN_ID of its own for its duration."""
    from tank_control.harness import domains, runner
    with domains.claimed() as domain, tempfile.TemporaryDirectory(prefix='sweep_') as tmp:
        env = {**os.environ, 'ROS_DOMAIN_ID': str(domain),
               'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
               domains.EXCLUSIVE_ENV: str(domain)}     # claimed empty: no discovery wait
        try:
            result = runner.run_scenario(scenario, tmp, env=env, plots=False)   # thrown away
        except runner.RunInterrupted:          # a stop signal stops the sweep (its files are
            raise KeyboardInterrupt from None  # temporary), finished runs are kept
        return result.metrics, result.trace


# ------------------------------------------------------------------------------ executors
class InlineExecutor(cf.Executor):
    """Runs each task at ``submit`` in the calling process (one worker, nothing to start)."""

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> cf.Future:
        future: cf.Future = cf.Future()
        try:
            future.set_result(fn(*args, **kwargs))
        except BaseException as exc:              # noqa: BLE001  (delivered through the future)
            future.set_exception(exc)
        return future


def local_executor(workers: int | None = None) -> cf.Executor:
    """Processes on this machine: ``workers`` (default every core this process may use);
    one worker runs in this process. Workers are forked from a fresh single-threaded server
    process (``forkserver``), not from this one: a process with threads (DDS, a Dask client)
    can be forked holding a lock that then never opens in the child."""
    n = workers or len(os.sched_getaffinity(0))
    if n < 1:
        raise SweepError(f'--workers {n}: at least 1')
    if n == 1:
        return InlineExecutor()
    import multiprocessing
    return cf.ProcessPoolExecutor(max_workers=n,
                                  mp_context=multiprocessing.get_context('forkserver'))


def dask_executor(address: str | None = None, scheduler_file: str | None = None
                  ) -> tuple[cf.Executor, Callable[[], None]]:
    """The ``concurrent.futures`` executor of a ``dask.distributed`` cluster, and how to close
    the client. Workers need tank_control importable (the same package installed)."""
    try:
        from distributed import Client
    except ImportError:
        raise SweepError('--cluster needs dask.distributed (pip install "dask[distributed]")'
                         ) from None
    try:
        client = (Client(scheduler_file=scheduler_file, timeout='30s') if scheduler_file
                  else Client(address, timeout='30s'))
    except (OSError, TimeoutError, ValueError) as exc:
        raise SweepError(f'cannot reach the Dask scheduler {scheduler_file or address}: '
                         f'{_one_line(exc)}') from None
    return client.get_executor(), client.close


# ------------------------------------------------------------------------------ the sweep
@dataclass(frozen=True)
class SweepProgress:
    done: int
    total: int
    failed: int
    skipped: int
    elapsed: float

    @property
    def eta(self) -> float:
        ran = self.done - self.skipped
        left = self.total - self.done
        return self.elapsed / ran * left if ran > 0 else math.inf


class ProgressBar:
    """``sweep [####------] 40/100 runs, 1 failed, 3.2 runs/s, ETA 19 s`` on a terminal (a line
    per 10 % in CI or a pipe)."""

    def __init__(self, stream: TextIO, tty: bool | None = None) -> None:
        self.stream = stream
        self.tty = (stream.isatty() and not os.environ.get('CI')) if tty is None else tty
        self._decile = -1

    def __call__(self, p: SweepProgress) -> None:
        width = 20
        filled = int(width * p.done / p.total) if p.total else width
        ran = p.done - p.skipped
        rate = ran / p.elapsed if p.elapsed > 0 else 0.0
        eta = '?' if not math.isfinite(p.eta) else f'{p.eta:.0f} s'
        text = (f'sweep [{"#" * filled}{"-" * (width - filled)}] {p.done}/{p.total} runs'
                + (f' ({p.skipped} already done)' if p.skipped else '')
                + f', {p.failed} failed, {rate:.1f} runs/s, ETA {eta}')
        if self.tty:
            self.stream.write('\r' + text.ljust(100) + ('\n' if p.done >= p.total else ''))
        else:
            decile = int(10 * p.done / p.total) if p.total else 10
            if decile == self._decile:
                return
            self._decile = decile
            self.stream.write(text + '\n')
        self.stream.flush()


@dataclass
class SweepResult:
    out_dir: Path
    rows: list[dict[str, Any]]
    files: dict[str, Path] = field(default_factory=dict)
    summary: dict[str, Any] = field(default_factory=dict)
    ran: int = 0
    skipped: int = 0
    run_wall: float = 0.0        # wall seconds from the first submission to the last result


def _read_done(path: Path) -> dict[str, dict[str, Any]]:
    """Finished runs of an earlier invocation (a torn last line is ignored)."""
    done: dict[str, dict[str, Any]] = {}
    if not path.exists():
        return done
    for line in path.read_text().splitlines():
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            continue
        if isinstance(record, dict) and record.get('status') in ('ok', 'failed'):
            done[record['key']] = record
    return done


def run_sweep(spec: SweepSpec, out_dir: str | Path, executor: cf.Executor,
              progress: Callable[[SweepProgress], None] | None = None,
              plots: bool = True) -> SweepResult:
    """Run every case not already in ``out_dir/runs.jsonl`` on ``executor``; write the table,
    summary and (unless ``plots`` is False: ``--no-plots``) the plots. Interrupting it
    (KeyboardInterrupt) keeps every finished run."""
    out = Path(out_dir)
    (out / 'traces').mkdir(parents=True, exist_ok=True)
    todo_cases = cases(spec)
    log_path = out / 'runs.jsonl'
    done = _read_done(log_path)
    start = time.monotonic()
    records: dict[str, dict[str, Any]] = {}
    pending: dict[cf.Future, Case] = {}
    copies: dict[str, int] = {}                  # equal grid values give the same run: run once
    for case in todo_cases:
        copies[case.key] = copies.get(case.key, 0) + 1
    state = {'done': 0, 'failed': 0, 'skipped': 0}

    def count(record: Mapping[str, Any], skipped: bool = False) -> None:
        n = copies[record['key']]
        state['done'] += n
        state['failed'] += n * (record['status'] != 'ok')
        state['skipped'] += n * skipped

    def report() -> None:
        if progress:
            progress(SweepProgress(state['done'], len(todo_cases), state['failed'],
                                   state['skipped'], time.monotonic() - start))

    with log_path.open('a') as log:
        if log.tell() and not log_path.read_bytes().endswith(b'\n'):
            log.write('\n')                       # after a line torn by an interruption
        def finish(record: dict[str, Any]) -> None:
            npz = record.pop('trace_npz', None)
            if npz is not None:
                tmp = out / 'traces' / f'{record["key"]}.tmp.npz'
                tmp.write_bytes(npz)
                tmp.replace(out / 'traces' / f'{record["key"]}.npz')
            log.write(json.dumps(record, default=float) + '\n')    # Infinity/NaN kept
            log.flush()
            records[record['key']] = record
            count(record)

        submitted: set[str] = set()
        for case in todo_cases:
            if case.key in records or case.key in submitted:
                continue
            submitted.add(case.key)
            if case.key in done:
                records[case.key] = done[case.key]
                count(done[case.key], skipped=True)
            elif case.error:
                finish({'key': case.key, 'status': 'failed', 'reason': case.error,
                        'metrics': {}, 'wall_s': 0.0})
            else:
                pending[executor.submit(run_case, case.payload())] = case
        report()
        try:
            for future in cf.as_completed(pending):
                case = pending[future]
                try:
                    record = future.result()
                except Exception as exc:          # noqa: BLE001  (a lost worker: rerun resumes it)
                    record = {'key': case.key, 'status': 'lost', 'reason': _one_line(exc),
                              'metrics': {}, 'wall_s': 0.0}
                finish(record)
                report()
        except KeyboardInterrupt:
            for future in pending:
                future.cancel()
            raise
    rows = table_rows(todo_cases, records)
    result = SweepResult(out, rows, ran=len(pending), skipped=state['skipped'],
                         run_wall=time.monotonic() - start)
    result.files.update(write_table(rows, out))
    result.summary = summarize(rows, spec)
    result.files.update(write_summary(result.summary, out))
    if plots:
        from tank_control.harness.sweep_plots import plot_sweep
        result.files.update(plot_sweep(spec, todo_cases, rows, out))
    return result


def table_rows(all_cases: Sequence[Case], records: Mapping[str, Mapping[str, Any]]
               ) -> list[dict[str, Any]]:
    """One row per case: index, scenario, sample, the swept values, status, reason, key,
    wall time, then every metric."""
    swept: list[str] = []
    for case in all_cases:
        swept += [k for k in case.overrides if k not in swept]
    rows = []
    for case in all_cases:
        record = records.get(case.key, {'status': 'lost', 'reason': 'not run', 'metrics': {}})
        row: dict[str, Any] = {'run': case.index, 'scenario': case.scenario.name,
                               'sample': case.sample}
        row.update({k: case.overrides.get(k) for k in swept})
        row.update(status=record['status'], reason=record.get('reason', ''), key=case.key,
                   wall_s=record.get('wall_s'))
        row.update(record.get('metrics', {}))
        rows.append(row)
    return rows


def _columns(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    names: list[str] = []
    for row in rows:
        names += [k for k in row if k not in names]
    return names


def write_table(rows: Sequence[Mapping[str, Any]], out: Path) -> dict[str, Path]:
    """``results.csv`` and ``results.parquet`` (Parquet needs pyarrow)."""
    names = _columns(rows)
    csv_path = out / 'results.csv'
    with csv_path.open('w', newline='') as handle:
        writer = csv.writer(handle)
        writer.writerow(names)
        for row in rows:
            writer.writerow(['' if row.get(n) is None else _csv_value(row.get(n)) for n in names])
    files = {'table': csv_path}
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return files
    columns = {}
    for name in names:
        values = [row.get(name) for row in rows]
        present = [v for v in values if v is not None]
        if present and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                           for v in present) and any(isinstance(v, float) for v in present):
            values = [None if v is None else float(v) for v in values]
        elif present and not all(isinstance(v, type(present[0])) for v in present):
            values = [None if v is None else json.dumps(v) for v in values]
        elif present and isinstance(present[0], (list, dict)):
            values = [None if v is None else json.dumps(v) for v in values]
        columns[name] = pa.array(values)
    pq.write_table(pa.table(columns), out / 'results.parquet')
    files['parquet'] = out / 'results.parquet'
    return files


def _csv_value(value: Any) -> Any:
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, (list, dict)):
        return json.dumps(value)
    return value


def metric_columns(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    """The metric columns (numbers measured by the run, not its settings or bookkeeping)."""
    fixed = {*TABLE_FIXED, 'key', *NONDETERMINISTIC}
    swept = {k for row in rows for k in row if '.' in k and k.split('.')[0] in
             (*node_specs.NODES, HARNESS)}
    return [c for c in _columns(rows) if c not in fixed and c not in swept]


def summarize(rows: Sequence[Mapping[str, Any]], spec: SweepSpec) -> dict[str, Any]:
    """Per scenario and metric: runs, min, p5, p50, p95, max, and the worst run (largest, or
    smallest for margins and stability) with its swept values."""
    metrics = metric_columns(rows)
    swept = [c for c in _columns(rows) if c not in metrics and c not in
             (*TABLE_FIXED, 'key', *NONDETERMINISTIC)]
    out: dict[str, Any] = {'title': spec.title, 'claim': spec.claim, 'scenarios': {}}
    for name in dict.fromkeys(row['scenario'] for row in rows):
        mine = [r for r in rows if r['scenario'] == name]
        ok = [r for r in mine if r['status'] == 'ok']
        entry: dict[str, Any] = {'runs': len(mine), 'failed': len(mine) - len(ok),
                                 'failures': sorted({r['reason'] for r in mine
                                                     if r['status'] != 'ok'})[:5],
                                 'metrics': {}}
        for metric in metrics:
            values = [(r[metric], r) for r in ok if isinstance(r.get(metric), (int, float))
                      and not isinstance(r.get(metric), bool) and not math.isnan(r[metric])]
            if not values:
                continue
            arr = np.array([v for v, _ in values], dtype=float)
            smaller = metric.split('.')[-1] in SMALLER_IS_WORSE
            worst_value, worst_row = (min if smaller else max)(values, key=lambda x: x[0])
            finite = arr[np.isfinite(arr)]
            pct = (np.percentile(finite, [5, 50, 95]).tolist() if finite.size
                   else [math.nan] * 3)
            if float(arr.min()) == float(arr.max()):
                worst_row = {}                    # every run alike: no worst case to name
            entry['metrics'][metric] = {
                'n': int(arr.size), 'min': float(arr.min()), 'p5': pct[0], 'p50': pct[1],
                'p95': pct[2], 'max': float(arr.max()), 'worst': float(worst_value),
                'worse': 'smaller' if smaller else 'larger',
                'worst_run': worst_row.get('run'),
                'worst_at': {k: worst_row.get(k) for k in swept if worst_row.get(k) is not None}}
        out['scenarios'][name] = entry
    return out


KEY_METRICS = ('overshoot_pct', 'settling_time', 'iae', 'peak_error', 'constraint_violations',
               'ms', 'gain_margin', 'phase_margin', 'delay_margin')


def summary_markdown(summary: Mapping[str, Any]) -> str:
    """The key metrics of the summary as a Markdown table: p50, the tail on the bad side (p95;
    p5 for a margin, where smaller is worse), the worst (largest; smallest for a margin) and
    where it occurred."""
    lines = []
    if summary.get('title'):
        lines.append(f'# {summary["title"]}\n')
    if summary.get('claim'):
        lines.append(f'Claim: {summary["claim"]}\n')
    lines.append('| scenario | metric | runs | p50 | p95 (margins: p5) | worst (margins: min) '
                 '| worst at |')
    lines.append('|---|---|---|---|---|---|---|')
    for name, entry in summary['scenarios'].items():
        shown = [m for m in entry['metrics'] if m.split('.')[-1] in KEY_METRICS]
        for metric in shown:
            s = entry['metrics'][metric]
            where = ', '.join(f'{k} = {_fmt(v)}' for k, v in s['worst_at'].items())
            tail = s['p5'] if s.get('worse') == 'smaller' else s['p95']
            lines.append(f'| {name} | {metric} | {s["n"]} | {_fmt(s["p50"])} | {_fmt(tail)} '
                         f'| {_fmt(s["worst"])} | {where} |')
        if entry['failed']:
            lines.append(f'| {name} | failed runs | {entry["failed"]} | | | | '
                         f'{"; ".join(entry["failures"])} |')
    return '\n'.join(lines) + '\n'


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        if math.isnan(value):
            return '–'
        return f'{value:.4g}'
    return str(value)


def write_summary(summary: Mapping[str, Any], out: Path) -> dict[str, Path]:
    from tank_control.harness.runner import jsonable
    (out / 'summary.json').write_text(json.dumps(jsonable(summary), indent=2,
                                                 allow_nan=False) + '\n')
    (out / 'summary.md').write_text(summary_markdown(summary))
    return {'summary': out / 'summary.md', 'summary_json': out / 'summary.json'}

