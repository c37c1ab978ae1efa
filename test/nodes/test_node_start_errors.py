"""A user mistake on a node's command line is one line on stderr and exit status 2, never a
Python traceback: a ``--params-file`` that cannot be read or is not valid YAML (named with its
line and column), and a ROS argument rcl refuses. Every node executable of the package."""
from __future__ import annotations

import re
import subprocess

import pytest

NODES = ('plant_node', 'controller_node', 'reference_node', 'dashboard_node')


def one_line_failure(argv, env) -> str:
    out = subprocess.run(argv, capture_output=True, text=True, timeout=120, env=env)
    assert out.returncode == 2, (out.returncode, out.stderr)
    assert 'Traceback' not in out.stderr and 'File "' not in out.stderr, out.stderr
    lines = [line for line in out.stderr.splitlines() if not line.startswith('[ERROR] [')]
    assert len(lines) == 1, out.stderr
    return lines[0]


@pytest.mark.parametrize('node', NODES)
def test_yaml_syntax_error_in_params_file_names_file_and_line(node, node_cmd, ros_env, tmp_path):
    path = tmp_path / 'bad.yaml'
    path.write_text('plant:\n  ros__parameters:\n    plant: ipdt\n    gain: [0.05\n')
    line = one_line_failure(node_cmd(node, '--params-file', str(path)), ros_env)
    assert re.fullmatch(rf'{node}: {re.escape(str(path))}:5:1: not valid YAML: .*'
                        r'\(while parsing a flow sequence at line 4\)', line), line


def test_missing_params_file_and_a_bad_ros_argument(node_cmd, ros_env, tmp_path):
    line = one_line_failure(node_cmd('plant_node', '--params-file', str(tmp_path / 'no.yaml')),
                            ros_env)
    assert line == f'plant_node: --params-file {tmp_path / "no.yaml"}: cannot read ' \
                   '(No such file or directory)'
    line = one_line_failure(node_cmd('reference_node', '-r', 'foo'), ros_env)
    assert line.startswith("reference_node: failed to initialize rcl: Couldn't parse remap rule")


@pytest.mark.parametrize('node', NODES)
def test_help_says_how_the_node_takes_parameters_and_exits(node, node_cmd, ros_env):
    """`ros2 run tank_control <node> --help` prints a usage and an example instead of starting
    the node (which would ignore the flag and run)."""
    out = subprocess.run(node_cmd(node) + ['--help'], capture_output=True, text=True,
                         timeout=60, env=ros_env)
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith(f'usage: {node} [-h] [--ros-args [--params-file FILE]')
    assert f'ros2 run tank_control {node} --ros-args --params-file config/' in out.stdout
