"""The main job (``make demo``): the mixing tank of [Michalski2021] in lockstep over a real ROS 2 graph.

Runs ``config/scenarios/tank_mpcs_qp.yaml`` — the nonlinear tank of [Michalski2021] §1 under the
offset-free MPCS-QP of [Michalski2021] §6 at its default horizons (N, Nu, block) = (600, 200, 10) with
[Michalski2021]'s λ = 0.5, within the document's constraints
0 ≤ F_H, F_Cin ≤ 100 cm³/s and |ΔF| ≤ 0.2 cm³/s per sample, warm-started at the operating point;
setpoint changes on h and T_out and ±25 % steps of F_D, 9100 s simulated — as three node
processes plus the harness's recorder, then prints the metrics table, the inputs' ranges and
constraint violations, and where the plot, trace and recording are. Comparison with the
two-loop PI: docs/mpcs.md.

    python -m tank_control.demo [--out DIR] [--scenario FILE] [--duration S] [--in-process]
"""
from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence
from pathlib import Path

DEFAULT_SCENARIO = 'scenarios/tank_mpcs_qp.yaml'


def config_dir() -> Path:
    """The shipped scenarios (:func:`~tank_control.harness.scenario_file.shipped_config_dir`)."""
    from tank_control.harness.scenario_file import shipped_config_dir
    return shipped_config_dir()


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='python -m tank_control.demo', description=__doc__.split('\n\n')[0])
    parser.add_argument('--scenario', type=Path, default=config_dir() / DEFAULT_SCENARIO)
    parser.add_argument('--out', type=Path, default=Path('build') / 'demo')
    parser.add_argument('--duration', type=float, help='simulated seconds (default: the file\'s)')
    parser.add_argument('--in-process', action='store_true', help='no ROS graph (core/loop.py)')
    args = parser.parse_args(argv)
    # Keep the demo's DDS traffic on this machine unless the user chose otherwise.
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')

    from tank_control.harness.cli import ProgressPrinter
    from tank_control.harness.compare import markdown_table
    from tank_control.harness.runner import RunFailed, run
    from tank_control.harness.scenario_file import ScenarioError

    mode = 'in-process loop' if args.in_process else 'lockstep over ROS 2 (3 node processes)'
    print(f'tank_control demo: {args.scenario.name}, {mode}', flush=True)
    start = _start_text(args.scenario)
    if start:
        print(start, flush=True)
    try:
        result = run(args.scenario, args.out, mode=None if args.in_process else 'lockstep',
                     rtf=None if args.in_process else 0.0, duration=args.duration,
                     in_process=args.in_process, progress=ProgressPrinter(sys.stderr, 'demo'))
    except ScenarioError as err:
        print(f'demo: {err}', file=sys.stderr)
        return 2
    except RunFailed as err:
        print(f'demo: run failed: {err}', file=sys.stderr)
        return 1
    run_info = result.metrics['run']
    print()
    print(result.metrics.get('title') or result.name)
    print()
    print(markdown_table([result]), end='')
    print()
    inputs = result.metrics['inputs']
    for name, m in inputs.items():
        print(f'input {name}: min {m["min"]:.4g}, max {m["max"]:.4g}, total variation '
              f'{m["total_variation"]:.4g}, constraint violations {m["constraint_violations"]}')
    for warning in result.metrics.get('controller', {}).get('warnings', []):
        print(f'controller warning: {warning}')
    print(f'run: {run_info["ticks"]} ticks, {run_info["sim_duration"]:g} s simulated in '
          f'{run_info["wall_time"]:.1f} s wall ({run_info["ticks_per_s"]:.0f} ticks/s), '
          f'missed samples {run_info["missed_samples"]}, late samples {run_info["late_samples"]}')
    print()
    print(f'plot:      {result.files["plot"]}')
    print(f'trace:     {result.files["trace"]}')
    print(f'recording: {result.files["recording"]}')
    print(f'metrics:   {result.files["metrics"]}')
    return 0


def _start_text(scenario: Path) -> str:
    """How the run starts: the controller's bumpless take-over value (``initial_output``)."""
    from tank_control.core import scenario as core_scenario
    try:
        _, control = core_scenario.validate(core_scenario.sections_of(scenario))
    except ValueError:
        return ''            # the run reports a bad file with its reason
    values = control.settings.values
    flows = ', '.join(f'{name} {value:g}' for name, value in
                      zip(values['input_names'], values['initial_output']))
    return (f'start: the controller takes over bumplessly at initial_output ({flows}); '
            'no lead-in needed')


if __name__ == '__main__':
    sys.exit(main())
