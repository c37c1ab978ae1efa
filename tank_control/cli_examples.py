"""Examples shown under ``--help`` of every command of the project (``tank-control …`` and the
``ros2`` verbs it ships), as argparse epilogs: one table, keyed by the parser's ``prog``.

Every example is a command line that the parser accepts (test/cli/test_help_examples.py parses
each one); the scenarios and nodes they name are the shipped ones (``config/``, the node names
of the parameter files).
"""
from __future__ import annotations

import argparse

EXAMPLES: dict[str, tuple[str, ...]] = {
    'tank-control': (
        'tank-control list',
        'tank-control run config/ipdt_pid.yaml --out runs/ipdt',
        'tank-control compare config/scenarios/tank_pi.yaml config/scenarios/tank_pi_decoupled.yaml '
        '--out runs/cmp',
        'tank-control analyze config/fopdt_zn.yaml',
        'tank-control sweep config/ipdt_pid.yaml --out runs/dt --grid plant.dead_time=4,5,6',
    ),
    'tank-control list': (
        'tank-control list',
        'tank-control list --dir config/scenarios',
    ),
    'tank-control run': (
        'tank-control run config/ipdt_pid.yaml --out runs/ipdt',
        'tank-control run config/ipdt_pid.yaml --out runs/ipdt --in-process',
        'tank-control run config/ipdt_pid.yaml --out runs/x --mode sim --rtf 10 --duration 60',
        'tank-control run config/ipdt_pid.yaml --out runs/x --set plant.dead_time=6.0 '
        '--set controller.tuning.setpoint_weights=false',
        'tank-control run config/fopdt_autotune.yaml --out runs/at --rtf 1 --dashboard',
    ),
    'tank-control compare': (
        'tank-control compare config/scenarios/tank_pi.yaml config/scenarios/tank_pi_decoupled.yaml '
        '--out runs/cmp',
        'tank-control compare config/fopdt_zn.yaml config/fopdt_zn_ramp.yaml --out runs/zn '
        '--in-process',
    ),
    'tank-control assess': (
        'tank-control assess runs/x/trace.csv --pv y.y --sp r.y --op u.u --sample-time 0.5 '
        '--dead-time 2 --op-limits -50 50',
        'tank-control assess historian.csv --pv FIC101.PV --sp FIC101.SP --op FIC101.OP '
        '--sample-time 1 --time t --plot fic101.png',
    ),
    'tank-control analyze': (
        'tank-control analyze config/fopdt_zn.yaml',
        'tank-control analyze config/ipdt_pid.yaml --set controller.tuning.rule=experimental',
    ),
    'tank-control recover': (
        'tank-control recover runs/ipdt',
        'tank-control recover runs/ipdt --force',
    ),
    'tank-control sweep': (
        "tank-control sweep config/scenarios/ipdt_mdp_pi.yaml --out runs/pi "
        "--grid 'plant.dead_time=±20%:9' --grid plant.gain=0.04,0.05,0.06",
        "tank-control sweep config/ipdt_pid.yaml --out runs/mc "
        "--random 'plant.dead_time=normal(5,0.5)' --samples 200 --seed 1",
        'tank-control sweep config/studies/000_robustness.yaml --out runs/000 --workers 2',
    ),
    'ros2': (
        'ros2 run tank_control plant_node --ros-args --params-file config/ipdt_pid.yaml',
        'ros2 param set /controller kp 2.5',
        'ros2 topic echo /measurement',
        'ros2 service call /controller/start_autotune std_srvs/srv/Trigger',
        'ros2 node list',
    ),
    'ros2 run': (
        'ros2 run tank_control plant_node --ros-args --params-file config/ipdt_pid.yaml',
        'ros2 run tank_control controller_node --ros-args --params-file config/ipdt_pid.yaml',
        'ros2 run tank_control reference_node --ros-args --params-file config/ipdt_pid.yaml',
        'ros2 run tank_control dashboard_node',
        'ros2 run tank_control controller_node --ros-args -r __node:=level_controller '
        '--params-file config/tank_two_loop.yaml',
    ),
    'ros2 param': (
        'ros2 param list /controller',
        'ros2 param get /controller kp',
        'ros2 param set /controller kp 2.5',
        'ros2 param describe /controller kp',
        'ros2 param dump /controller',
        'ros2 param load /controller config/ipdt_pid.yaml',
    ),
    'ros2 param list': ('ros2 param list', 'ros2 param list /controller --filter tuning'),
    'ros2 param get': ('ros2 param get /controller kp', 'ros2 param get /controller autotune.ku'),
    'ros2 param set': ('ros2 param set /controller kp 2.5',
                       'ros2 param set /reference setpoint.y.value 2.0',
                       'ros2 param set /plant lockstep.paused false'),
    'ros2 param describe': ('ros2 param describe /controller kp ti',),
    'ros2 param dump': ('ros2 param dump /controller > controller.yaml',),
    'ros2 param load': ('ros2 param load /controller controller.yaml',),
    'ros2 topic': ('ros2 topic list -t', 'ros2 topic echo /measurement --once',
                   'ros2 topic hz /measurement'),
    'ros2 topic list': ('ros2 topic list', 'ros2 topic list -t'),
    'ros2 topic echo': ('ros2 topic echo /measurement',
                        'ros2 topic echo /controller/autotune_state',
                        'ros2 topic echo /diagnostics --once',
                        'ros2 topic echo /manipulated --field position'),
    'ros2 topic pub': (
        "ros2 topic pub --once /disturbance sensor_msgs/msg/JointState "
        "'{header: auto, name: [v], position: [-0.1]}'",),
    'ros2 topic hz': ('ros2 topic hz /measurement',),
    'ros2 topic info': ('ros2 topic info /measurement -v',),
    'ros2 topic type': ('ros2 topic type /measurement',),
    'ros2 node': ('ros2 node list', 'ros2 node info /controller'),
    'ros2 node list': ('ros2 node list', 'ros2 node list -a'),
    'ros2 node info': ('ros2 node info /plant',),
    'ros2 service': ('ros2 service list -t',
                     'ros2 service call /controller/start_autotune std_srvs/srv/Trigger'),
    'ros2 service list': ('ros2 service list -t',),
    'ros2 service call': ('ros2 service call /controller/start_autotune std_srvs/srv/Trigger',
                          'ros2 service call /controller/abort_autotune std_srvs/srv/Trigger'),
    'ros2 service type': ('ros2 service type /controller/start_autotune',),
    'ros2 daemon': ('ros2 daemon status', 'ros2 daemon stop'),
    'ros2 daemon start': ('ros2 daemon start', 'ros2 daemon start --idle-timeout 600'),
    'ros2 daemon stop': ('ros2 daemon stop',),
    'ros2 daemon status': ('ros2 daemon status',),
}


def epilog(prog: str) -> str | None:
    """The ``examples:`` block for the parser named ``prog`` (None if it has none)."""
    lines = EXAMPLES.get(prog)
    return None if not lines else 'examples:\n' + '\n'.join(f'  {line}' for line in lines)


def sub_parsers(parser: argparse.ArgumentParser) -> list[argparse.ArgumentParser]:
    """Every parser below ``parser`` (its sub-commands, recursively)."""
    found = []
    for action in parser._actions:                  # argparse has no public walk
        if isinstance(action, argparse._SubParsersAction):
            for child in dict.fromkeys(action.choices.values()):
                found.append(child)
                found.extend(sub_parsers(child))
    return found


def attach(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Give ``parser`` and every sub-parser its examples (the epilog, kept as written)."""
    for p in (parser, *sub_parsers(parser)):
        text = epilog(p.prog)
        if text:
            p.epilog = text
            if p.formatter_class is argparse.HelpFormatter:
                p.formatter_class = argparse.RawDescriptionHelpFormatter
    return parser
