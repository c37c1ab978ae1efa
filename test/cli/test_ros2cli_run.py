"""`ros2 run`, the hand-over to a real ros2cli, and `--help` of every verb."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap

import pytest
from support.ros2cli import FIXTURE_NODE, ros2, ros2_argv, ros2_parallel

VERBS = [('run',), ('param',), ('param', 'list'), ('param', 'get'), ('param', 'set'),
         ('param', 'describe'), ('param', 'dump'), ('param', 'load'), ('topic',),
         ('topic', 'list'), ('topic', 'echo'), ('topic', 'pub'), ('topic', 'hz'),
         ('topic', 'info'), ('topic', 'type'), ('node',), ('node', 'list'), ('node', 'info'),
         ('service',), ('service', 'list'), ('service', 'call'), ('service', 'type')]


def test_help_of_every_verb(ros_env, capsys):
    from tank_control.ros2cli.main import run_cli
    for verb in VERBS:      # in-process: argparse prints the usage and exits 0
        try:
            code = run_cli([*verb, '--help'])
        except SystemExit as leaving:
            code = leaving.code
        assert code in (0, None), verb
        assert capsys.readouterr().out.startswith(f'usage: ros2 {" ".join(verb)}'), verb
    top, unknown = ros2_parallel(ros_env, ('--help',), ('param', 'frobnicate'))
    assert top.returncode == 0 and top.stdout.startswith('usage: ros2')
    assert all(command in top.stdout for command in ('run', 'param', 'topic', 'node', 'service'))
    assert unknown.returncode != 0 and 'invalid choice' in unknown.stderr


def test_hands_over_to_a_real_ros2cli(ros_env, tmp_path):
    """With ros2cli importable, its `ros2cli.cli:main` runs with the unchanged argv."""
    package = tmp_path / 'ros2cli'
    package.mkdir()
    (package / '__init__.py').write_text('')
    (package / 'cli.py').write_text(textwrap.dedent('''\
        import sys
        def main():
            print('real ros2cli got', sys.argv[1:])
            return 7
    '''))
    env = dict(ros_env, PYTHONPATH=os.pathsep.join(
        [str(tmp_path), *filter(None, [ros_env.get('PYTHONPATH')])]))
    result = subprocess.run(ros2_argv('param', 'get', '/plant', 'kp'), env=env,
                            capture_output=True, text=True, timeout=30)
    assert result.returncode == 7, result.stderr
    assert result.stdout == "real ros2cli got ['param', 'get', '/plant', 'kp']\n"


@pytest.fixture
def ament_prefix(tmp_path):
    """A colcon-like install prefix with package ``fake_pkg`` in its ament index."""
    prefix = tmp_path / 'install'
    index = prefix / 'share' / 'ament_index' / 'resource_index' / 'packages'
    index.mkdir(parents=True)
    (index / 'fake_pkg').write_text('')
    lib = prefix / 'lib' / 'fake_pkg'
    lib.mkdir(parents=True)
    scripts = {'fixture_node': f'exec "{sys.executable}" "{FIXTURE_NODE}" "$@"',
               'exit3': 'echo "args: $*"; exit 3',
               'not_executable': 'exit 0'}
    for name, body in scripts.items():
        path = lib / name
        path.write_text(f'#!/bin/sh\n{body}\n')
        path.chmod(0o644 if name == 'not_executable' else 0o755)
    return prefix


def test_run_resolves_and_reports_like_ros2cli(ros_env, ament_prefix):
    env = dict(ros_env, AMENT_PREFIX_PATH=str(ament_prefix))
    exit3, no_package, no_exe, not_exec, console_script = ros2_parallel(
        env,
        ('run', 'fake_pkg', 'exit3', '--ros-args', '-p', 'a:=1'),
        ('run', 'no_such_pkg', 'x'),
        ('run', 'fake_pkg', 'no_such_exe'),
        ('run', 'fake_pkg', 'not_executable'),
        # pip install (no <prefix>/lib/tank_control): the declared console scripts.
        ('run', 'tank_control', 'ros2', '--help'))
    assert exit3.returncode == 3                      # the executable's exit code
    assert exit3.stdout == 'args: --ros-args -p a:=1\n'
    assert (no_package.returncode, no_package.stderr) == (1, "Package 'no_such_pkg' not found\n")
    assert (no_exe.returncode, no_exe.stderr) == (1, 'No executable found\n')
    assert (not_exec.returncode, not_exec.stderr) == (1, 'No executable found\n')
    assert console_script.returncode == 0, console_script.stderr
    assert console_script.stdout.startswith('usage: ros2')
    missing = ros2(env, 'run', 'tank_control', 'no_such_exe')
    assert (missing.returncode, missing.stderr) == (1, 'No executable found\n')


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_run_passes_ros_args_and_signals(sig, procs, probe, ros_env, ament_prefix):
    env = dict(ros_env, AMENT_PREFIX_PATH=str(ament_prefix))
    proc = procs.start('run', ros2_argv('run', 'fake_pkg', 'fixture_node', '--ros-args',
                                        '-r', '__node:=runner', '-p', 'gain:=2.5'), env=env)
    assert probe.wait_for(lambda: 'runner' in probe.node.get_node_names(), 60), proc.tail()
    got = ros2(env, 'param', 'get', '/runner', 'gain')
    assert got.stdout.strip() == 'Double value is: 2.5', got.stderr
    # The signal to `ros2 run` (not to its process group) stops the node cleanly.
    proc.popen.send_signal(sig)
    assert proc.popen.wait(timeout=30) == 0, proc.tail()
