"""Run a scenario: node processes + recorder (ROS), or the in-process loop; write the results.

``run_scenario`` leaves ``scenario.yaml``, ``trace.csv``, ``run.mcap``, ``metrics.json``,
``plot.png``, ``analysis.png`` (a SISO loop that describes itself linearly, or the two-loop PI
per loop: ``harness/analysis.py``)
and (ROS runs) ``logs/<node>.log`` in the output directory. How a ROS run proceeds (start
paused, wait for the graph, un-pause, record, stop) and what ends it: docs/harness.md.
``trace.csv`` and ``run.mcap`` are written as the run goes (``stream.py``); a failed or
interrupted run (SIGINT, SIGTERM, SIGHUP: ``signals.py``) leaves them valid up to that
moment, with ``"complete": false`` and the ``reason`` in metrics.json (docs/harness.md,
"Interrupted and failed runs"). The domain is checked before anything starts (``domains.py``)
and its graph while the nodes start, before tick 0 (``graph_check.py``); the node processes die
with the harness (``processes.py``).
Times in the results are plant time (stamp − the plant's ``time_origin``).
"""
from __future__ import annotations

import gc
import json
import math
import os
import shutil
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from tank_control.core import loop as core_loop
from tank_control.core import scenario as core_scenario
from tank_control.core.control.kinds.registry import KINDS as CONTROLLER_KINDS
from tank_control.core.monitoring.modes import ModeLog
from tank_control.core.params import ConfigError
from tank_control.core.trace import Trace
from tank_control.harness import metrics as metrics_mod
from tank_control.harness.analysis_ahead import AnalysisAhead
from tank_control.harness.domains import (domain_of, exclusive_domain, local_only, lock_run,
                                          participants_on, start_profile_env)
from tank_control.harness.graph_check import foreign_graph
from tank_control.harness.processes import ProcessGroup
from tank_control.harness.recording import TraceMessages
from tank_control.harness.scenario_file import (Scenario, ScenarioError, effective_harness,
                                                load_scenario, node_parameters, run_value,
                                                write_params_file)
from tank_control.harness.signals import RunInterrupted, StopSignals
from tank_control.harness.stream import RecordingStream, RunOutputs
from tank_control.harness.trace import GATED_DISTURBANCE, HELD_IN_LOCKSTEP
from tank_control.nodes.messages import MATCH_WAIT_S, TOPIC_RECORDED

__all__ = ['RunFailed', 'RunInterrupted', 'RunResult', 'Progress', 'run', 'run_scenario',
           'run_metrics', 'simulate']

NS = 1_000_000_000
#: while a run goes, how often the node processes are checked for life and finished trace rows
#: are written [s, wall]
CHECK_PERIOD = 0.01
OUTPUT_FILES = ('trace.csv', 'run.mcap', 'metrics.json', 'plot.png', 'analysis.png')
PUBLISHES = {'plant': ('measurement', '/clock'), 'reference': ('setpoint', 'disturbance'),
             'controller': ('manipulated',)}
SUBSCRIBES = {'plant': ('manipulated', 'disturbance'), 'reference': ('/clock',),
              'controller': ('measurement', 'setpoint')}
#: wall: the reference and the controller schedule on the plant's time origin instead of /clock
SUBSCRIBES_WALL = {**SUBSCRIBES, 'reference': ('time_origin',),
                   'controller': ('measurement', 'setpoint', 'time_origin')}
#: lockstep: ticks the plant may run ahead of the recorder (``lockstep.record_window``), and
#: every how many ticks the recorder acknowledges (half of it: a recorder that keeps up never
#: holds the plant back)
RECORD_WINDOW = 8
ACK_EVERY = 4
#: Topics whose publishers mean another graph on the domain (besides the node names).
GRAPH_TOPICS = ('measurement', 'setpoint', 'manipulated', 'disturbance', '/clock',
                GATED_DISTURBANCE)


#: What an external node (``harness.external_nodes``) must read for the harness to take it as
#: up (besides its publishers, ``PUBLISHES``): the signal it answers.
EXTERNAL_READS = {'plant': ('manipulated',), 'controller': ('measurement',),
                  'reference': ('/clock',)}
#: Wall seconds between two lines saying what the harness waits for from an external node.
EXTERNAL_NOTICE_EVERY = 5.0


def _notice(line: str) -> None:
    """One line for the user while a run starts (stderr)."""
    print(f'tank-control: {line}', file=sys.stderr, flush=True)


#: Wall seconds a node killed hard may stay in the graph after its restart (its DDS
#: participant's lease; measured: docs/harness.md "Restarts") without counting as a second
#: node of its name.
GHOST_LEASE = 30.0
#: run.mcap topic of the harness's own events (a node's restart), ``rcl_interfaces/msg/Log``.
HARNESS_EVENTS = '/harness/events'


def harness_event(text: str, stamp_ns: int) -> Any:
    """A ``HARNESS_EVENTS`` message for run.mcap (``RawMessage``), stamped ``stamp_ns`` (the
    loop's time), received now."""
    from rcl_interfaces.msg import Log
    from rclpy.serialization import serialize_message

    from tank_control.harness.recording import RawMessage
    msg = Log(level=Log.WARN, name='tank_control_harness', msg=text)
    msg.stamp.sec, msg.stamp.nanosec = divmod(stamp_ns, NS)
    return RawMessage(HARNESS_EVENTS, 'rcl_interfaces/msg/Log', serialize_message(msg),
                      time.time_ns(), stamp_ns)


class RunFailed(RuntimeError):
    """The run could not complete; the message says why (a node's last log lines). Whatever
    was recorded is in the output directory, marked ``"complete": false``."""

    partial_results: Path | None = None     # that directory, once written


@dataclass(frozen=True)
class Progress:
    """Where a run is: simulated seconds done, of how many, at what pace, and when it ends."""

    sim_time: float
    duration: float
    rate: float          # simulated seconds per wall second
    ticks_per_s: float
    eta: float           # wall seconds left (inf while unknown)


ProgressFn = Callable[[Progress], None]


@dataclass
class RunResult:
    """What a run left behind."""

    name: str
    out_dir: Path
    trace: Trace
    metrics: dict[str, Any]
    files: dict[str, Path] = field(default_factory=dict)


NodeCommand = Callable[[str], list[str]]
"""Node name → the argv that starts it, before ``--ros-args``."""


def node_module_command(node: str) -> list[str]:
    """``python -m tank_control.nodes.<node>_node`` with this interpreter."""
    return [sys.executable, '-m', f'tank_control.nodes.{node}_node']


def run(scenario_path: str | Path, out_dir: str | Path, *, mode: str | None = None,
        rtf: float | None = None, duration: float | None = None, overrides: Sequence[str] = (),
        in_process: bool = False, env: Mapping[str, str] | None = None,
        progress: ProgressFn | None = None, dashboard: int | None = None,
        plots: bool = True) -> RunResult:
    """Load ``scenario_path`` with ``overrides`` and the command-line settings, and run it."""
    scenario = effective_harness(load_scenario(scenario_path, overrides), mode, rtf, duration)
    return run_scenario(scenario, out_dir, in_process=in_process, env=env, progress=progress,
                        dashboard=dashboard, plots=plots)


def run_scenario(scenario: Scenario, out_dir: str | Path, *, in_process: bool = False,
                 env: Mapping[str, str] | None = None, progress: ProgressFn | None = None,
                 node_command: NodeCommand = node_module_command,
                 dashboard: int | None = None, plots: bool = True) -> RunResult:
    """Run a loaded scenario into ``out_dir`` (steps of a ROS run: docs/harness.md). SIGINT,
    SIGTERM and SIGHUP stop the run cleanly while it goes (when called from the main thread).
    ``dashboard``: also start dashboard_node on this port for the run (a ROS run only).
    ``plots``: False writes no ``plot.png`` and ``analysis.png`` (``--no-plots``: batch runs,
    a sweep's runs); the trace, recording and metrics are the same."""
    if dashboard is not None and in_process:
        raise ScenarioError('--dashboard watches the nodes of a ROS run; an --in-process run '
                            'has none')
    reason = size_reason(scenario, in_process)
    if reason:
        raise ScenarioError(f'{scenario.path}: {reason}')
    if in_process and scenario.harness.external_nodes:
        raise ScenarioError(f'{scenario.path}: harness.external_nodes: '
                            f'{", ".join(scenario.harness.external_nodes)} run as programs of '
                            'their own, which an --in-process run cannot include; allowed [] '
                            'with --in-process')
    out = Path(out_dir)
    with StopSignals() as stop:
        if in_process:
            return _run_in_process(scenario, out, progress, stop, plots)
        return _RosRun(scenario, out, env, progress, node_command, stop, dashboard,
                       plots).execute()


def prepare_output(scenario: Scenario, out: Path) -> Path:
    """Create ``out`` without the results of an earlier run; write ``scenario.yaml``."""
    out.mkdir(parents=True, exist_ok=True)
    for stale in OUTPUT_FILES:                    # a failed run must not leave old results
        (out / stale).unlink(missing_ok=True)
    return write_params_file(scenario, out / 'scenario.yaml')


#: memory a run holds per plant tick, an upper estimate [bytes]: in-process the trace table
#: and its copies (up to 16 columns of float64, 4 copies); a ROS run's recorder and trace rows
BYTES_PER_TICK = {'in_process': 16 * 8 * 4, 'ros': 4096}


def available_memory() -> int | None:
    """MemAvailable of /proc/meminfo [bytes], None where it cannot be read."""
    try:
        for line in Path('/proc/meminfo').read_text().splitlines():
            if line.startswith('MemAvailable:'):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def size_reason(scenario: Scenario, in_process: bool) -> str | None:
    """Why a run is too long for this machine: its ticks (``harness.duration`` over the
    plant's ``sample_time``) would need more than half the available memory; None if it fits."""
    duration = scenario.harness.duration
    sample_time = float(scenario.params('plant').get('sample_time', 0.1))
    ticks = int(duration / sample_time) + 1
    need = ticks * BYTES_PER_TICK['in_process' if in_process else 'ros']
    available = available_memory()
    if available is None or need <= available / 2:
        return None
    return (f'harness.duration: {duration:g} s at the plant sample_time {sample_time:g} s is '
            f'{ticks:.3g} ticks, which would need about {need / 2**30:.3g} GiB of memory; '
            f'{available / 2**30:.3g} GiB are available: shorten the run or lengthen the tick')


# ----------------------------------------------------------------------------------------------
# Results common to both kinds of run

def controller_report(scenario: Scenario, controller_params: Mapping[str, Any]
                      ) -> tuple[dict[str, tuple[float, float]], dict[str, Any]]:
    """Input limits ``{channel: (min, max)}`` and final gains of the controller that ran, from
    its parameter values (read from the node, or from the in-process controller) through its
    kind."""
    if 'controller' not in scenario.harness.started:    # none, or the user's own program
        return {}, {}
    setup = core_scenario.controller_setup(controller_params, given=())
    kind, settings = setup.kind, setup.settings
    limits = dict(kind.input_limits(settings)) if kind.input_limits is not None else {}
    return limits, {name: settings.values[name] for name in kind.gains}


def _planned_report(scenario: Scenario) -> tuple[dict[str, tuple[float, float]], dict[str, Any]]:
    """``controller_report`` from the file's values (a run that ended before the node could
    be asked); nothing for a controller this package does not know."""
    try:
        return controller_report(scenario, scenario.params('controller'))
    except (ConfigError, ValueError, KeyError, TypeError):
        return {}, {}


def run_metrics(scenario: Scenario, trace: Trace, controller_params: Mapping[str, Any],
                complete: bool = True, plant_only: bool = False,
                cases_ahead: list[Any] | None = None, modes: list[Any] | None = None
                ) -> tuple[dict[str, Any], list[Any]]:
    """The measured part of ``metrics.json`` (events, outputs, inputs, controller, loop
    analysis) and the loop cases it was analysed on; also what a sweep records per run
    (``plant_only``: the loop analysed on the plant's model only, not also on the
    controller's own model, which a sweep does not report). ``complete=False`` (a failed or
    stopped run): what can be known, the controller's limits and gains from the file when the
    node could not be asked, no error from the report. ``cases_ahead``: the loop cases
    already built for these parameters (``analysis_ahead``). ``modes``: the controller's
    manual / fail-safe changes (``run.controller_modes``)."""
    if complete:
        limits, gains = controller_report(scenario, controller_params)
        warnings = controller_warnings(controller_params)
    else:
        limits, gains = (controller_report(scenario, controller_params) if controller_params
                         else _planned_report(scenario))
        try:
            warnings = controller_warnings(controller_params)
        except (ConfigError, ValueError, KeyError, TypeError):
            warnings = []
    body = metrics_mod.trace_metrics(
        trace, {name: limits.get(name, (-math.inf, math.inf)) for name in trace.channels('u')})
    autotune = {k: v for k, v in controller_params.items() if k.startswith('autotune.')}
    summary = controller_summary(controller_params)
    robustness = {k: v for k, v in controller_params.items() if k.startswith('robustness.')}
    from tank_control.core.scenario_loops import loop_cases
    cases: list[Any] = []
    analysis_note = ''
    if 'controller' in scenario.harness.started and controller_params:
        try:
            cases = (cases_ahead if cases_ahead is not None
                     else loop_cases(scenario.sections, controller_params))
            if plant_only:
                cases = [case for case in cases if case.label.startswith('plant')]
        except (ConfigError, ValueError) as exc:
            analysis_note = f'analysis.png not written: {exc}'
        if not cases and not analysis_note and not plant_only:
            # the two-loop PI's loops, or why none (MPCS); a sweep's rows do not use them
            from tank_control.harness.analysis import run_loop_analysis
            analysis_note = run_loop_analysis(scenario.sections, controller_params)
    metrics = {
        **body,
        'controller': {'final_gains': gains, 'input_limits': {k: list(v) for k, v in limits.items()},
                       **({'autotune': autotune} if autotune else {}),
                       **({'summary': summary} if summary else {}),
                       **({'robustness': robustness} if robustness else {}),
                       'warnings': warnings,
                       'parameters': dict(controller_params)},
        'loop_analysis': {case.label: {k: v for k, v in vars(case.report()).items()}
                          for case in cases} or analysis_note or None,
    }
    from tank_control.harness.performance import trace_performance
    ms = next((m for m in (metrics['loop_analysis'][c.label].get('ms') for c in cases
                           if c.label.startswith('plant')) if m is not None), None) \
        if isinstance(metrics['loop_analysis'], dict) else None
    metrics['loop_performance'] = trace_performance(trace, scenario.sections, controller_params,
                                                    limits, ms=ms, modes=modes)
    return metrics, cases


def finish(scenario: Scenario, out: Path, trace: Trace, run_info: dict[str, Any],
           controller_params: Mapping[str, Any], files: Mapping[str, Path],
           reason: str | None = None, ahead: AnalysisAhead | None = None,
           plots: bool = True) -> RunResult:
    """Write metrics.json, plot.png and analysis.png next to the trace and recording already
    written; ``reason``: why the run is not complete (None: it is); ``ahead``: the loop
    analysis computed during the run, used if it was for ``controller_params``; ``plots``:
    False draws neither figure."""
    cases_ahead = ahead.take(controller_params) if ahead is not None else None
    measured, cases = run_metrics(scenario, trace, controller_params, complete=reason is None,
                                  cases_ahead=cases_ahead,
                                  modes=run_info.get('controller_modes'))
    metrics = {
        'scenario': scenario.name,
        'title': scenario.harness.title,
        'claim': scenario.harness.claim,
        'overrides': list(scenario.overrides),
        'mode': run_info.get('mode'),
        'complete': reason is None,
        'reason': reason,
        **{k: measured[k] for k in ('outputs', 'inputs', 'events')},
        'run': run_info,
        'controller': measured['controller'],
        'loop_analysis': measured['loop_analysis'],
        'loop_performance': measured['loop_performance'],
    }
    files = {**files, 'metrics': out / 'metrics.json'}
    title = analysis_title(scenario)
    if plots and cases:
        from tank_control.harness.analysis import plot_analysis
        placed = ahead.place(out / 'analysis.png') if ahead and cases_ahead is not None else None
        files['analysis'] = placed or plot_analysis(cases, out / 'analysis.png', title=title)
    elif plots and isinstance(metrics['loop_analysis'], dict):   # the two-loop PI, per loop
        from tank_control.harness.analysis import plot_run_two_loop
        drawn = plot_run_two_loop(scenario.sections, controller_params, out / 'analysis.png',
                                  title=title)
        if drawn is not None:
            files['analysis'] = drawn
    files['metrics'].write_text(json.dumps(jsonable(metrics), indent=2, allow_nan=False) + '\n')
    if len(trace) and plots:
        from tank_control.harness.plotting import plot_runs, run_plot
        files['plot'] = plot_runs([run_plot(scenario.name, trace, metrics)], out / 'plot.png',
                                  title=scenario.harness.title or scenario.name)
    return RunResult(scenario.name, out, trace, metrics, files)


def analysis_title(scenario: Scenario) -> str:
    return f'{scenario.harness.title or scenario.name}: final gains'


def run_metadata(scenario: Scenario, mode: str) -> dict[str, str]:
    """What run.mcap says of its run (``recording.RUN_METADATA``; ``tank-control recover``
    reads it): the scenario's name and path, the overrides (JSON), the clock mode."""
    return {'scenario': scenario.name, 'path': str(scenario.path),
            'overrides': json.dumps(list(scenario.overrides)), 'mode': mode,
            'title': scenario.harness.title, 'claim': scenario.harness.claim}


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip() or type(exc).__name__
    return text.splitlines()[0]


def controller_summary(controller_params: Mapping[str, Any]) -> str:
    """The kind's one-line summary of what the controller found (``ControllerKind.summary``;
    the relay auto-tuner: Ku, Tu, model and gains), '' when it has none."""
    name = controller_params.get('controller')
    if not isinstance(name, str) or name not in CONTROLLER_KINDS:
        return ''
    summary = CONTROLLER_KINDS[name].summary
    return summary(controller_params) if summary is not None else ''


def controller_warnings(controller_params: Mapping[str, Any]) -> list[str]:
    """The configuration warning the controller gives for its final parameters (its
    ``warning``, which controller_node logs and shows in /diagnostics; e.g. MPCS horizons
    shorter than the plant's dead times), as a list: empty when there is none."""
    if 'controller' not in controller_params:
        return []
    setup = core_scenario.controller_setup(controller_params, given=())
    controller = setup.kind.build(setup.settings)
    warning = str(getattr(controller, 'warning', '') or '')
    return [warning] if warning else []


def jsonable(value: Any) -> Any:
    """``value`` as strict JSON: numpy numbers as Python numbers, non-finite floats as null."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, (np.floating, float)):
        value = float(value)
        return value if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


def _as_failure(exc: BaseException, out: Path) -> BaseException:
    """What to raise for ``exc`` after the partial results were written to ``out`` (noted
    on the exception as ``partial_results`` for the command line's message)."""
    if isinstance(exc, OSError):
        exc = RunFailed(str(exc))
    if isinstance(exc, (RunFailed, RunInterrupted)):
        exc.partial_results = out
    return exc


# ----------------------------------------------------------------------------------------------
# In-process (core/loop.py, no ROS)

def _build(scenario: Scenario) -> core_scenario.Built:
    """The core objects of the sections the node processes would read (``node_parameters``,
    what scenario.yaml holds), built as the nodes build them; ``ScenarioError`` (one line)
    for a value the core objects reject."""
    try:
        return core_scenario.build(node_parameters(scenario))
    except (ConfigError, ValueError) as exc:
        raise ScenarioError(f'{scenario.path}: {exc}') from None


def simulate(scenario: Scenario) -> tuple[Trace, core_scenario.Built]:
    """Run a loaded scenario through core/loop.py for its ``harness.duration`` (the table
    in memory, nothing written); ``ScenarioError`` (one line) for a value the core objects
    reject or a run too large for the memory (``size_reason``)."""
    reason = size_reason(scenario, in_process=True)
    if reason:
        raise ScenarioError(f'{scenario.path}: {reason}')
    built = _build(scenario)
    try:
        return core_scenario.run(built, scenario.harness.duration).until(
            scenario.harness.duration), built
    except (ConfigError, ValueError) as exc:
        raise ScenarioError(f'{scenario.path}: {exc}') from None


def _state_name(controller: Any) -> str | None:
    """The controller's named state (the relay auto-tuner's ``idle``, ``relay``, ...), if any."""
    state = getattr(controller, 'state', None)
    return state if isinstance(state, str) else None


def _run_in_process(scenario: Scenario, out: Path, progress: ProgressFn | None,
                    stop: StopSignals, plots: bool = True) -> RunResult:
    config = scenario.harness
    built = _build(scenario)
    modes = ModeLog()           # the manual / fail-safe changes, as controller_node logs them
    try:
        rows = core_loop.iter_loop(built.plant, built.controller, built.reference,
                                   sample_time=built.sample_time, duration=config.duration,
                                   noise=built.noise.sample_floats, guards=built.guards(),
                                   modes=modes.add)
    except (ConfigError, ValueError) as exc:    # a parameter the core objects reject: one line
        raise ScenarioError(f'{scenario.path}: {exc}') from None
    names = core_loop.loop_columns(built.plant, built.controller, built.reference)
    prepare_output(scenario, out)
    outputs = RunOutputs(out, metadata=run_metadata(scenario, 'in_process'))
    start = last_report = time.monotonic()
    failure: BaseException | None = None
    states: list[tuple[float, str]] = []       # the controller's state changes (relay auto-tuner)
    state = _state_name(built.controller)
    try:
        messages = TraceMessages(outputs.recording, names)
        for k, row in enumerate(rows):
            outputs.trace.add(names, row)
            messages.add(row)
            now_state = _state_name(built.controller)
            if now_state != state:
                state = now_state
                states.append((float(row[0]), str(state)))
            if k % 64 == 0:
                stop.check()
                outputs.flush_now_and_then()
                now = time.monotonic()
                if progress and now - last_report >= 0.5:
                    last_report = now
                    _report_in_process(progress, float(row[0]), config.duration, k + 1,
                                       now - start)
    except BaseException as exc:               # noqa: B902 - partial results, then re-raised
        failure = exc
    wall = time.monotonic() - start
    trace = outputs.close()
    ticks = len(trace)
    sim = float(trace.t[-1]) if ticks else 0.0
    if progress and failure is None:
        _report_in_process(progress, config.duration, config.duration, ticks, wall)
    run_info = {
        'mode': 'in_process', 'sim_duration': sim,
        'wall_time': wall, 'ticks': ticks, 'ticks_per_s': ticks / max(wall, 1e-9),
        'missed_samples': 0, 'late_samples': 0, 'max_jitter': 0.0,
        'late_by_signal': {prefix: 0 for prefix in ('r', 'u', 'd') if trace.channels(prefix)},
        'recording': 'run.mcap written from the trace (in-process run: no ROS messages exist)',
        **({'controller_states': states} if states else {}),
        **({'controller_modes': modes.changes} if modes.changes else {}),
    }
    files = {'trace': outputs.trace.path, 'recording': outputs.recording.path}
    if failure is not None:
        finish(scenario, out, trace, run_info, {}, files, _first_line(failure), plots=plots)
        raise _as_failure(failure, out)
    return finish(scenario, out, trace, run_info, built.controller_values(), files,
                  plots=plots)


def _report_in_process(progress: ProgressFn, sim: float, duration: float, ticks: int,
                       wall: float) -> None:
    rate = sim / max(wall, 1e-9)
    progress(Progress(sim, duration, rate, ticks / max(wall, 1e-9),
                      (duration - sim) / rate if rate > 0 else math.inf))


# ----------------------------------------------------------------------------------------------
# ROS run

def _warm_up() -> None:
    """Import what writes the results (matplotlib: about a second on a loaded machine) while
    the harness waits for discovery anyway, instead of at the end."""
    import tank_control.harness.analysis  # noqa: F401
    import tank_control.harness.plotting  # noqa: F401


def due_periods(scenario: Scenario, mode: str, tick_ns: int | None) -> dict[str, int]:
    """Prefix → the period [ns] at which an answer is due (``harness/trace.py``, README "Late
    samples"): ``u`` every controller ``sample_time``; ``r`` and ``d`` every reference
    ``sample_time`` in wall, every tick otherwise. A ``sample_time`` the scenario does not
    state is the node's declared default (the controller kind's, the reference's): the node
    samples on that, not on the plant's tick. A period that is no whole number of ticks is
    taken as the tick."""
    def period(node: str) -> int | None:
        try:
            value = run_value(scenario, node, 'sample_time')
        except ConfigError:          # a kind without a sample time of its own
            return tick_ns
        ns = int(round(value * NS)) if isinstance(value, (int, float)) and value > 0 else None
        return ns if ns and tick_ns and ns % tick_ns == 0 else tick_ns
    external = scenario.harness.external_nodes      # the user's programs: due every tick
    reference = period('reference') if mode == 'wall' and 'reference' not in external else tick_ns
    due = {'u': period('controller') if 'controller' not in external else tick_ns,
           'r': reference, 'd': reference}
    return {k: v for k, v in due.items() if v}


class _RosRun:
    def __init__(self, scenario: Scenario, out: Path, env: Mapping[str, str] | None,
                 progress: ProgressFn | None, node_command: NodeCommand,
                 stop: StopSignals, dashboard: int | None = None, plots: bool = True) -> None:
        self.node_command = node_command
        self.dashboard = dashboard
        self.plots = plots
        self.scenario = scenario
        self.config = scenario.harness
        self.out = out
        self.params_file = out / 'scenario.yaml'
        self.env = start_profile_env(env if env is not None else os.environ)
        self.env['PYTHONUNBUFFERED'] = '1'
        self.domain = domain_of(self.env)
        self.progress = progress
        self.stop = stop
        self.group: ProcessGroup | None = None
        self.created_out = False
        self.ahead: AnalysisAhead | None = None    # the loop analysis, computed during the run
        self.nobody_before = False                 # no participant on the domain at the start
        self.duration_ns = int(round(self.config.duration * NS))
        self.mode = self.config.clock_mode
        self.started = self.config.started            # the nodes it starts
        self.external = self.config.external_nodes    # the nodes the user runs
        self.t0_ns: int | None = 0 if self.mode != 'wall' else None
        self.phase = 'while starting'
        self.cpu: dict[str, float] = {}            # CPU seconds during the run, by process
        plant = scenario.params('plant')
        self.record_window = (RECORD_WINDOW if self.mode == 'lockstep'
                              and 'plant' in self.started else 0)
        sample_time = plant.get('sample_time')
        self.sample_time = (float(sample_time) if isinstance(sample_time, (int, float))
                            and not isinstance(sample_time, bool) and sample_time > 0 else None)
        self.tick_ns = int(round(self.sample_time * NS)) if self.sample_time else None
        self.stream: RecordingStream | None = None
        self.restarts: list[dict[str, Any]] = []   # nodes started again (on_node_exit restart)
        self._restarted_at = -math.inf            # wall time of the latest restart [monotonic s]
        self._ghosts: dict[str, list[float]] = {}  # name → until when a dead one may be listed
        self.foreign: dict[str, dict[str, Any]] = {}   # nodes on the domain it did not start

    @property
    def _procs(self) -> ProcessGroup:
        """The run's node processes (from the start of the nodes to their stop)."""
        assert self.group is not None, 'no nodes started'
        return self.group

    @property
    def _recording(self) -> RecordingStream:
        """The run's recording (from the recorder's start to the results)."""
        assert self.stream is not None, 'no recording'
        return self.stream

    # -- processes --------------------------------------------------------------------------
    def _argv(self, node: str) -> list[str]:
        argv = [*self.node_command(node), '--ros-args', '--params-file', str(self.params_file)]
        # Sim: the others' timers run on /clock. Lockstep: they follow the plant's stamps
        # (clock_mode lockstep is in their sections), so no time source and no /clock reader.
        if self.mode == 'sim' and node != 'plant':
            argv += ['-p', 'use_sim_time:=true']
        if node == 'plant':
            argv += ['-p', 'lockstep.paused:=true']      # un-paused once the graph is up
            if self.record_window:       # never more ticks ahead of the recording than this
                argv += ['-p', f'lockstep.record_window:={self.record_window}']
        return argv

    def _check_alive(self) -> None:
        self.stop.check()
        if self.stream is not None:     # every wait passes here: run.mcap at most 0.25 s behind
            self.stream.outputs.flush_now_and_then()
        for name, proc in list(self.group.processes.items() if self.group else ()):
            code = proc.returncode
            if code is None:
                continue
            why = self._no_restart(name)
            if why is None:
                self._restart(name, code)
                continue
            raise RunFailed(f'node {name} exited with code {code} {self.phase}{why}; '
                            f'last lines of {proc.log_path}:\n{proc.tail(15)}')

    def _no_restart(self, name: str) -> str | None:
        """None if node ``name`` is to be started again after its exit (``harness.on_node_exit:
        restart``), else what to add to the reason the run ends ('' for on_node_exit abort)."""
        config = self.config
        if config.on_node_exit != 'restart':
            return ''
        if self.phase == 'while starting':
            return ' (harness.on_node_exit restart acts once the run goes)'
        if name == 'plant':
            return (' (harness.on_node_exit restart does not restart the plant: its clock and '
                    'state are the run)')
        done = sum(r['node'] == name for r in self.restarts)
        if done >= config.max_restarts:
            return f' after {done} restarts (harness.max_restarts {config.max_restarts})'
        return None

    def _restart(self, name: str, code: int) -> None:
        """Start node ``name`` again with its parameters (docs/nodes.md, "Restarts": it takes
        over on the running loop), mark it in run.mcap (``HARNESS_EVENTS``) and the metrics.

        Lockstep: the plant is paused over the restart, until the recorder's readers have
        matched the new process's writers (and, for a node that reports it on /diagnostics,
        its writers the readers the graph shows: ``_await_matched``, each side of a match is
        discovered on its own), so that every answer of the new node is recorded
        (a writer's first messages reach only the readers that matched it, and the plant, which
        needs only its own answer, would run up to ``record_window`` ticks whose answers the
        recording then lacks)."""
        rec, group = self.recorder, self.group
        if group is None:
            return
        topics = [t for t in PUBLISHES.get(name, ()) if not t.startswith('/')]
        pause = bool(topics) and self.mode == 'lockstep' and 'plant' in group.processes
        if pause:
            self._set_paused(True, name)
        stamp = rec.latest.get('measurement')
        sim = (stamp - self._origin()) / NS if stamp is not None else None
        attempt = sum(r['node'] == name for r in self.restarts) + 1
        text = (f'node {name} exited with code {code} at {sim if sim is not None else 0:g} s; '
                f'restarted ({attempt} of {self.config.max_restarts}, harness.on_node_exit '
                'restart)')
        self.restarts.append({'node': name, 'time': sim, 'exit_code': code, 'attempt': attempt})
        # A node killed hard stays in the others' graph until its participant's lease ends.
        self._ghosts.setdefault(name, []).append(time.monotonic() + GHOST_LEASE)
        # Writers matched before, per topic; a dead node's writer stays matched until its
        # lease ends (GHOST_LEASE), so the new one is there once the count exceeds the least
        # count seen since the kill.
        least = {t: rec.matched_publishers(t) for t in topics}
        proc = group.restart(name, text)
        if self.stream is not None:
            self.stream.on_message(harness_event(text, stamp if stamp is not None
                                                 else time.time_ns()))

        def matched() -> bool:
            counts = {t: rec.matched_publishers(t) for t in topics}
            for t, count in counts.items():
                least[t] = min(least[t], count)
            return all(counts[t] > least[t] for t in topics)

        def alive() -> None:
            self.stop.check()
            if self.stream is not None:
                self.stream.outputs.flush_now_and_then()
            if proc.returncode is not None:
                raise RunFailed(f'node {name} exited with code {proc.returncode} right after '
                                f'its restart; last lines of {proc.log_path}:\n{proc.tail(15)}')
        if topics and not rec.spin_until(matched, self.config.startup_timeout, alive):
            raise RunFailed(f'node {name} was restarted, but the recorder did not match its '
                            f'publishers ({", ".join(topics)}) within '
                            f'{self.config.startup_timeout:g} s (harness.startup_timeout)')
        if name in ('plant', 'controller'):    # and its writers the recorder's readers
            self._await_matched([name])
        if pause:
            self._set_paused(False, name)
        self._restarted_at = time.monotonic()

    def _set_paused(self, paused: bool, name: str) -> None:
        """Pause or resume the lockstep plant's clock over the restart of ``name``."""
        reason = self.recorder.set_parameters('plant', {'lockstep.paused': paused},
                                              self.config.startup_timeout, self.stop.check)
        if reason:
            raise RunFailed(f'could not {"pause" if paused else "resume"} the plant\'s clock '
                            f'over the restart of {name}: {reason}')

    # -- recording ----------------------------------------------------------------------------
    def _origin(self) -> int:
        """The plant's time origin [ns] (wall: its ``time_origin``, else the first measurement)."""
        if self.t0_ns is None:
            rec = self.recorder
            self.t0_ns = rec.latest.get('time_origin', rec.first.get('measurement', 0))
        return self.t0_ns

    def _prepare(self) -> None:
        """The output directory: scenario.yaml (the nodes' parameters), logs/, and the
        recording's files (a run that fails from here on leaves its results)."""
        self.created_out = not self.out.exists()
        prepare_output(self.scenario, self.out)
        self.group = ProcessGroup(self.out / 'logs')
        due = due_periods(self.scenario, self.mode, self.tick_ns)
        self.stream = RecordingStream(self.out, self._origin, self.duration_ns, self.tick_ns, due,
                                      self.sample_time,
                                      held=HELD_IN_LOCKSTEP if self.mode == 'lockstep' else (),
                                      metadata=run_metadata(self.scenario, self.mode))

    def _refuse(self, found: str) -> None:
        """Another graph was seen before tick 0: stop this run's nodes and remove what it
        wrote (the output directory if it made it), then refuse."""
        if self.group is not None:
            self.group.stop_all()
            self.group = None
        if self.stream is not None:
            self.stream.close(complete=False)
            self.stream = None
        if self.created_out:
            shutil.rmtree(self.out, ignore_errors=True)
        else:
            for name in (*OUTPUT_FILES, 'scenario.yaml'):
                (self.out / name).unlink(missing_ok=True)
            shutil.rmtree(self.out / 'logs', ignore_errors=True)
        raise RunFailed(f'another graph is running on ROS_DOMAIN_ID {self.domain} '
                        f'({found}); this run would mix with it, so it did not start; '
                        'stop it or set a different ROS_DOMAIN_ID')

    def _look_before_starting(self, joined: float) -> None:
        """Step 2 of docs/harness.md when somebody may be on the domain (not ``nobody_before``):
        look for another graph for ``harness.discovery_time`` since the recorder joined,
        before any node of this run starts — a node started beside a running loop would take
        part in it (answer its plant's ticks) until the refusal."""
        from tank_control.harness.recorder import RECORDER_NAME
        rec = self.recorder
        found = foreign_graph(rec.node, rec.spin_once, GRAPH_TOPICS, self.config.discovery_time,
                              (RECORDER_NAME,), self.stop.check, since=joined,
                              started=self.external)     # the user's nodes: accepted once
        if found:
            self._refuse(found)

    def _look_while_starting(self) -> None:
        """Step 2 of docs/harness.md, continued: while this run's nodes come up, until every
        node of the run is in the graph, a second node of one of their names or a publisher of
        the run's topics from a node it did not start is another graph's. Before it the graph
        was quiet: nobody on the domain (``nobody_before``: a domain held exclusively,
        ``domains.exclusive_domain``, or LOCALHOST discovery and no participant on this host,
        ``domains.participants_on``; a participant that joins later announces itself at once),
        or ``_look_before_starting`` found nobody."""
        from tank_control.harness.recorder import RECORDER_NAME
        rec = self.recorder
        nodes = list(self.started)
        timeout = time.monotonic() + self.config.startup_timeout

        def check() -> None:
            self._check_alive()
            if time.monotonic() > timeout:
                raise RunFailed(f'the nodes {", ".join(nodes)} did not all come up within '
                                f'{self.config.startup_timeout:g} s (harness.startup_timeout); '
                                'node logs:\n' + '\n'.join(
                                    f'--- {name} ---\n{proc.tail(8)}'
                                    for name, proc in self._procs.processes.items()))
        # an external node (harness.external_nodes) is accepted once, as a node it started
        found = foreign_graph(rec.node, rec.spin_once, GRAPH_TOPICS, 0.0, (RECORDER_NAME,),
                              check, started=[*nodes, *self.external],
                              ready=lambda: set(nodes) <= rec.node_names())
        if found:
            self._refuse(found)

    # -- run ----------------------------------------------------------------------------------
    def execute(self) -> RunResult:
        if not self.domain.isdigit():
            raise RunFailed(f'ROS_DOMAIN_ID {self.domain!r} is not a domain number')
        lock, reason = lock_run(self.domain, str(self.out.resolve()))
        if reason:
            raise RunFailed(reason)
        try:
            return self._execute()
        finally:
            lock.release()

    def _execute(self) -> RunResult:
        import rclpy
        from rclpy.context import Context

        from tank_control.harness.recorder import Recorder
        from tank_control.nodes.runtime import quiet_collector

        # Nobody on the domain before this run: no graph to wait for (step 0)
        self.nobody_before = exclusive_domain(self.env) or (
            local_only(self.env) and not participants_on(int(self.domain)))
        context = Context()
        rclpy.init(context=context, args=['--ros-args', '--disable-rosout-logs'],
                   domain_id=int(self.domain))     # the nodes' domain
        recorder: Recorder | None = None
        failure: BaseException | None = None
        controller_params: dict[str, Any] = {}
        reference_params: dict[str, Any] = {}
        codes: dict[str, int] = {}
        wall_start = time.monotonic()
        run_wall = 0.0
        run_start: float | None = None
        try:
            recorder = Recorder(context, subscribe=False, tick_ns=self.tick_ns)
            joined = time.monotonic()              # its participant is on the domain
            self.recorder = recorder
            self._prepare()
            recorder.subscribe(self._recording.on_message)   # what the nodes say from their start
            if not self.nobody_before:             # somebody may be there: look first (step 2)
                if self.plots:
                    _warm_up()                     # while DDS discovers the domain
                self._look_before_starting(joined)
            # The graph is looked at while the nodes come up, too (step 2).
            nodes = self.started
            for node in nodes:
                self._procs.start(node, self._argv(node), env=self.env)
            if self.dashboard is not None:       # watches only; stopped with the nodes
                self._procs.start('dashboard', [*self.node_command('dashboard'), '--ros-args',
                                               '-p', f'port:={self.dashboard}'], env=self.env)
            # the results' imports, then the loop analysis, in a thread while the run goes on
            self.ahead = AnalysisAhead(self.scenario, self.out, analysis_title(self.scenario),
                                       draw=self.plots)
            self._look_while_starting()
            # an external plant_node started with lockstep.record_window waits for these too
            if self.record_window or (self.mode == 'lockstep' and 'plant' in self.external):
                signals = [t for node in self.config.nodes for t in PUBLISHES[node]
                           if not t.startswith('/')]
                recorder.acknowledge(signals, ACK_EVERY * (self.tick_ns or 0))
            if self.external:
                self._await_external()
            self._await_graph(nodes)
            quiet_collector()      # the recorder's arrival times: no long collection in the run
            cpu_start = self._cpu_seconds()
            run_start = time.monotonic()
            if 'plant' in nodes:
                self._unpause()
            elif 'plant' in self.external:    # runs its own clock; released if held
                self._unpause_external()
            self.phase = 'during the run'
            self.ahead.start(recorder.node_parameters('controller', 5.0, self._check_alive)
                             if 'controller' in nodes else {})
            self._run_loop(run_start)
            run_wall = time.monotonic() - run_start
            self.cpu = {name: end - start for name, end in self._cpu_seconds().items()
                        if end is not None and (start := cpu_start.get(name)) is not None}
            self.phase = 'at the end of the run'
            controller_params = (recorder.node_parameters('controller', 5.0, self._check_alive)
                                 if 'controller' in nodes else {})
            reference_params = (recorder.node_parameters('reference', 5.0, self._check_alive)
                                if 'reference' in nodes else {})
        except BaseException as exc:               # noqa: B902 - results so far, then re-raised
            failure = exc
            if run_start is not None:
                run_wall = time.monotonic() - run_start
        finally:
            gc.unfreeze()          # a harness may run again in this process (sweeps, tests)
            if self.group is not None:
                codes = self.group.stop_all()
            if recorder is not None:
                if failure is not None and self.stream is not None:
                    recorder.drain(1.0)            # what the nodes sent before they stopped
                recorder.destroy()
            rclpy.try_shutdown(context=context)
        if self.stream is None:                    # refused or failed before writing anything
            raise failure if failure is not None else RunFailed('the run did not start')
        return self._results(failure, controller_params, reference_params, codes, run_wall,
                             time.monotonic() - wall_start)

    def _cpu_seconds(self) -> dict[str, float | None]:
        """CPU time used so far by each node process and by this (harness) process [s]."""
        out = {name: proc.cpu_seconds() for name, proc in self._procs.processes.items()}
        out['harness'] = time.process_time()
        return out

    def _await(self, condition: Callable[[], bool], what: str) -> None:
        if not self.recorder.spin_until(condition, self.config.startup_timeout, self._check_alive):
            details = '\n'.join(f'--- {name} ---\n{proc.tail(8)}'
                                for name, proc in self._procs.processes.items())
            raise RunFailed(f'{what} within {self.config.startup_timeout:g} s '
                            f'(harness.startup_timeout); node logs:\n{details}')

    def _unpause(self) -> None:
        """Release tick 0 (``lockstep.paused`` false; plant_node acts on it at once)."""
        reason = self.recorder.set_parameters('plant', {'lockstep.paused': False},
                                              self.config.startup_timeout, self._check_alive)
        if reason:
            raise RunFailed(f'could not start the plant\'s clock: {reason}')

    def _unpause_external(self) -> None:
        """An external plant that holds its clock (plant_node started with ``-p
        lockstep.paused:=true``, so that the recorder sees tick 0) is released like the
        harness's own; one without that parameter (or not paused) runs its own clock."""
        held = self.recorder.node_parameters('plant', 5.0, self._check_alive)
        if held.get('lockstep.paused') is True:
            self._unpause()

    def _await_graph(self, nodes: Sequence[str]) -> None:
        """Every node in the graph and every publisher the recorder needs matched
        (in lockstep the plant holds tick 0 until it is un-paused); fail if the names are
        taken twice (another run on the same ROS_DOMAIN_ID would mix into this one)."""
        rec = self.recorder
        topics = [topic for node in nodes for topic in PUBLISHES[node]
                  if not (topic == '/clock' and self.mode == 'wall')]   # no sim clock in wall
        windowed = self.record_window and 'plant' in nodes
        # sim/wall: the plant does not wait for answers, so the nodes' inputs must be there too;
        # lockstep: so that tick 0 is answered at once instead of re-sent after resend_period
        subscribes = SUBSCRIBES_WALL if self.mode == 'wall' else SUBSCRIBES
        readers = [(node, topic) for node in nodes for topic in subscribes.get(node, ())]
        self._await(lambda: (set(nodes) <= rec.node_names()
                             and all(rec.publisher_count(t) > 0 for t in topics)
                             and all(node in rec.subscriber_nodes(t) for node, t in readers)
                             and (not windowed or rec.subscriber_count(TOPIC_RECORDED) > 0)
                             # matched by the recorder's readers: tick 0 reaches it at once
                             and all(rec.matched_publishers(t) > 0 for t in topics)),
                    'the graph did not come up (nodes ' + ', '.join(nodes)
                    + '; publishers of ' + ', '.join(topics)
                    + ''.join(f'; {node} subscribed to {t}' for node, t in readers) + ')')
        if self.mode != 'lockstep' and 'plant' in nodes:
            self._await_matched([node for node in ('plant', 'controller') if node in nodes])
        self._check_no_other_graph()

    def _external_missing(self, node: str) -> str | None:
        """What of external node ``node`` the harness still waits for (None: it is there):
        the node in the graph, its publishers (``PUBLISHES``; the plant's ``/clock`` not in
        wall) from that node and matched by the recorder's readers, its subscription to the
        signal it answers (``EXTERNAL_READS``)."""
        rec = self.recorder
        if node not in rec.node_names():
            return f'no node named {node} in the graph yet'
        for topic in PUBLISHES[node]:
            if topic == '/clock' and self.mode == 'wall':
                continue
            full = topic if topic.startswith('/') else '/' + topic
            writers = [info.node_name for info in rec.node.get_publishers_info_by_topic(full)]
            if node not in writers:
                return f'no publisher on {topic} yet'
            if rec.matched_publishers(topic) < len(writers):
                return f'its publisher on {topic} not yet matched by the recorder'
        for topic in EXTERNAL_READS[node]:
            if topic == '/clock' and self.mode == 'wall':
                continue
            if node not in rec.subscriber_nodes(topic):
                return f'no subscription to {topic} yet'
        return None

    def _await_external(self) -> None:
        """Wait (at most ``harness.external_wait`` wall seconds) until every node of
        ``harness.external_nodes`` is in the graph with its endpoints matched, saying what it
        waits for on stderr (once at first, then every ``EXTERNAL_NOTICE_EVERY`` s and when it
        changes); ``RunFailed`` naming what is missing when the time is up."""
        wait = self.config.external_wait
        start = time.monotonic()
        said: tuple[str, float] | None = None

        def missing() -> tuple[str, str] | None:
            for node in self.external:
                what = self._external_missing(node)
                if what is not None:
                    return node, what
            return None

        def check() -> None:
            nonlocal said
            self._check_alive()
            gap = missing()
            if gap is None:
                return
            now = time.monotonic()
            line = f'waiting for the external {gap[0]}: {gap[1]}'
            if said is None or said[0] != line or now - said[1] >= EXTERNAL_NOTICE_EVERY:
                _notice(f'{line} ({now - start:.0f} s of {wait:g} s, harness.external_wait)')
                said = (line, now)

        if not self.recorder.spin_until(lambda: missing() is None, wait, check):
            node, what = missing() or ('node', 'it')
            raise RunFailed(f'the external {node} did not come within {wait:g} s '
                            f'(harness.external_wait): {what}; start it (named {node}, '
                            f'on ROS_DOMAIN_ID {self.domain}) or raise harness.external_wait')

    def _await_matched(self, nodes: Sequence[str]) -> None:
        """sim/wall, where nobody waits for a tick: the plant's writers (measurement, time
        origin, applied input, /clock) have matched every reader this graph shows and its
        inputs every writer, and the controller's readers of the reference's signals every
        writer (``matched_*`` in their /diagnostics, sent at once on a change before they
        start). The graph comes from the participants' announcements; a node's own view can
        miss another node for seconds on a loaded machine (one lost announcement waits for the
        next, 3 s later): the plant's origin then reached that reference 2.8 s late, and the
        run lost its first 28 setpoints. Waits at most MATCH_WAIT_S (an endpoint of
        incompatible QoS never matches), then the clock starts anyway."""
        from diagnostic_msgs.msg import DiagnosticArray

        rec = self.recorder
        reported: dict[str, dict[str, int]] = {}

        def on_diagnostics(msg: DiagnosticArray) -> None:
            for status in msg.status:
                node = status.name.split(':')[0]        # 'plant', 'controller: pid'
                if node in nodes:
                    reported[node] = {kv.key: int(kv.value) for kv in status.values
                                      if kv.key.startswith(('matched_readers.',
                                                            'matched_writers.'))}

        def matched() -> bool:
            for counts in reported.values():
                for key, count in counts.items():
                    kind, _, topic = key.partition('.')
                    shown = (rec.node.count_subscribers(topic) if kind == 'matched_readers'
                             else rec.node.count_publishers(topic))
                    if count < shown:
                        return False
            return set(reported) == set(nodes)

        sub = rec.node.create_subscription(DiagnosticArray, '/diagnostics', on_diagnostics, 10)
        try:
            rec.spin_until(matched, MATCH_WAIT_S, self._check_alive)
        finally:
            rec.node.destroy_subscription(sub)

    def _check_no_other_graph(self) -> None:
        counts = self.recorder.node_counts()
        now = time.monotonic()
        for name, until in self._ghosts.items():       # restarted: the dead one's lease
            until[:] = [t for t in until if t > now]
        taken = [name for name in self.config.nodes if counts.get(name, 0) > (
            1 + len(self._ghosts.get(name, ())) if name in self._procs.processes
            else 1 if name in self.external else 0)]
        if self.phase == 'during the run':
            self._note_foreign(counts)
        if taken:
            raise RunFailed(f'node name(s) {", ".join(taken)} already in use on ROS_DOMAIN_ID '
                            f'{self.domain}: another graph is running there and would mix into '
                            'this run; stop it or set a different ROS_DOMAIN_ID')

    def _note_foreign(self, counts: Mapping[str, int]) -> None:
        """Remember every node on the domain that the harness did not start (reported at the
        end: ``run.foreign_nodes``): when first and last seen [s of plant time]."""
        from tank_control.harness.recorder import RECORDER_NAME
        ours = {*(self.group.processes if self.group else ()), *self.external, RECORDER_NAME}
        sim_ns = self._sim_ns()
        sim = sim_ns / NS if sim_ns is not None else 0.0
        for name in counts:
            if name.lstrip('/') in ours:
                continue
            seen = self.foreign.setdefault(name, {'node': name, 'first_seen': sim})
            seen['last_seen'] = sim

    def _sim_ns(self) -> int | None:
        """Plant time of the latest measurement (wall: from the plant's time origin, or the
        first measurement for a plant that publishes none)."""
        stamp = self.recorder.latest.get('measurement')
        if stamp is None:
            return None
        return stamp - self._origin()

    def _run_loop(self, run_start: float) -> None:
        rec = self.recorder
        last_progress = last_graph_check = -math.inf
        last_sim, last_move = -1, time.monotonic()
        while True:
            # The recorder takes every message of CHECK_PERIOD in one call (``spin_for``: five
            # a lockstep tick); the liveness check (a waitid per node), the trace's row writing
            # and the checks below run once per CHECK_PERIOD, not per message.
            self._check_alive()
            self._recording.advance()
            rec.spin_for(CHECK_PERIOD)
            now = time.monotonic()
            if now - last_graph_check >= 0.5:      # a graph that joins later mixes in too
                last_graph_check = now
                self._check_no_other_graph()
            sim = self._sim_ns()
            if sim is not None and sim != last_sim:
                last_sim, last_move = sim, now
            elif now - max(last_move, self._restarted_at) > self.config.stall_timeout:
                raise RunFailed(self._stall_message())
            if self.progress and now - last_progress >= 0.5 and sim is not None:
                last_progress = now
                self._report(sim, now - run_start)
            if sim is not None and sim >= self.duration_ns:
                break
        if self.mode == 'lockstep':
            self._await_last_answers()
        if self.progress:
            self._report(min(self._sim_ns() or 0, self.duration_ns), time.monotonic() - run_start)

    def _await_last_answers(self) -> None:
        """Lockstep: the plant moved past the duration, so every answer of the last tick
        inside it exists; wait until the recorder holds them too."""
        rec = self.recorder
        last = self._last_tick_within()
        answers = [t for t in ('setpoint', 'manipulated', 'disturbance') if t in rec.latest]
        if not rec.spin_until(lambda: all(rec.latest.get(t, -1) >= last for t in answers),
                              self.config.stall_timeout, self._check_alive):
            raise RunFailed(f'answers for the last tick ({last / NS:g} s) did not reach the recorder '
                            f'within {self.config.stall_timeout:g} s')

    def _last_tick_within(self) -> int:
        ts = self.scenario.params('plant').get('sample_time')
        if isinstance(ts, (int, float)) and ts > 0:
            ts_ns = int(round(ts * NS))
            return (self.duration_ns // ts_ns) * ts_ns
        return self.duration_ns

    def _stall_message(self) -> str:
        rec = self.recorder
        latest = ', '.join(f'{t} {s / NS:g} s' for t, s in sorted(rec.latest.items())) or 'nothing'
        tails = '\n'.join(f'--- {name} ---\n{proc.tail(8)}'
                          for name, proc in self._procs.processes.items())
        external = (f'; the external node(s) {", ".join(self.external)} (run by you, not by the '
                    'harness) may have stopped answering' if self.external else '')
        return (f'simulated time stopped moving for {self.config.stall_timeout:g} s '
                f'(harness.stall_timeout){external}; latest stamps: {latest}; node logs:\n{tails}')

    def _report(self, sim_ns: int, wall: float) -> None:
        if self.progress is None:
            return
        sim = sim_ns / NS
        rate = sim / wall if wall > 0 else 0.0
        ts = self.scenario.params('plant').get('sample_time')
        ticks = sim / ts / wall if isinstance(ts, (int, float)) and ts > 0 and wall > 0 else 0.0
        eta = (self.config.duration - sim) / rate if rate > 0 else math.inf
        self.progress(Progress(sim, self.config.duration, rate, ticks, max(eta, 0.0)))

    # -- results ------------------------------------------------------------------------------
    def _results(self, failure: BaseException | None, controller_params: dict[str, Any],
                 reference_params: dict[str, Any], codes: Mapping[str, int], run_wall: float,
                 total_wall: float) -> RunResult:
        """Finish trace.csv and run.mcap with everything received, write metrics.json and
        plot.png; raise the failure (or ``RunFailed`` for a run that recorded nothing) after."""
        stream = self._recording
        trace = stream.close(complete=failure is None)
        ticks = len(trace)
        if failure is None and ticks == 0:
            failure = RunFailed(f'the recording holds no measurement within the '
                                f'{self.config.duration:g} s of the run (topic measurement: '
                                f'{self.recorder.counts.get("measurement", 0)} messages)')
        rec = self.recorder
        has_origin = 'time_origin' in rec.latest
        if self.mode != 'wall' or has_origin:
            stream.stamps.start_ns = self.t0_ns if self.t0_ns is not None else 0
        sampling = stream.stamps.result()
        if self.mode == 'wall':
            # Stamps of a wall-clock plant lie on its timer's grid; the jitter a consumer sees
            # is in the arrival times (timer jitter plus transport), measured by the recorder.
            sampling['max_jitter'] = stream.arrivals.result()['max_jitter']
        run_info = {
            'mode': self.mode,
            'real_time_factor': self.config.real_time_factor,
            'sim_duration': float(trace.t[-1]) if ticks else 0.0,
            'wall_time': run_wall,
            'wall_time_total': total_wall,
            'ticks': ticks,
            'ticks_per_s': ticks / run_wall if run_wall > 0 else 0.0,
            # CPU per tick during the run (from un-pausing the plant to the last tick) of each
            # node process and of the harness (recorder, acknowledgments, progress) [ms]
            'cpu_ms_per_tick': {name: 1e3 * seconds / ticks for name, seconds in self.cpu.items()}
            if ticks else {},
            'missed_samples': sampling['missed_samples'],
            'late_samples': int(sum(trace.late.values())),
            'late_by_signal': trace.late,
            'max_jitter': sampling['max_jitter'],
            'messages': dict(rec.counts),
            'messages_after_row_written': stream.joiner.after_written,
            'unreadable_messages': stream.unreadable,
            'rejected_future': rec.future.refused,     # signals stamped too far ahead
            'record_window': self.record_window,
            'exit_codes': dict(codes),
            'restarts': list(self.restarts),
            'foreign_nodes': sorted(self.foreign.values(), key=lambda n: n['first_seen']),
        }
        states = stream.states.result()
        if states:
            run_info['controller_states'] = states
        if stream.modes.changes:           # controller_node's manual / fail-safe changes
            run_info['controller_modes'] = stream.modes.result()
        files = stream.files
        if failure is None:
            return finish(self.scenario, self.out, trace, run_info, controller_params, files,
                          ahead=self.ahead, plots=self.plots)
        finish(self.scenario, self.out, trace, run_info, controller_params, files,
               _first_line(failure), ahead=self.ahead, plots=self.plots)
        raise _as_failure(failure, self.out)
