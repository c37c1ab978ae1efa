"""The example package examples/heater_kinds (issue 32 §3), installed into the venv by `make
setup` (pip install -e): its kinds reach every process through their entry points with no
edit to tank_control — `tank-control list --kinds`, a lockstep run whose every node is started
with `ros2 run tank_control <node>` (equal to the in-process loop to 1e-9), a sweep on two
local workers, and the package's own tests (the conformance kit)."""
from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from support.ros2cli import ros2_argv

from tank_control.core.control.kinds import registry
from tank_control.harness import runner
from tank_control.harness.scenario_file import effective_harness, load_scenario
from tank_control.testing import check_controller_kind, check_plant_kind

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / 'examples' / 'heater_kinds'
SCENARIO = EXAMPLE / 'scenarios' / 'heater_on_off.yaml'
INSTALL = 'pip install -e examples/heater_kinds (make setup does it)'


@pytest.fixture(autouse=True)
def installed():
    assert registry.PLUGINS.origins.get('on_off') == 'tank-heater-kinds', INSTALL


def cli(env, *args, timeout=300):
    return subprocess.run([sys.executable, '-m', 'tank_control.harness.cli', *args], env=env,
                          capture_output=True, text=True, timeout=timeout, cwd=ROOT)


def test_list_kinds_shows_where_each_kind_comes_from(ros_env):
    out = cli(ros_env, 'list', '--kinds')
    assert out.returncode == 0, out.stderr
    rows = {line.split()[0]: line.split()[1] for line in out.stdout.splitlines()
            if line.startswith('  ')}
    assert rows['on_off'] == rows['heater'] == 'tank-heater-kinds'
    assert rows['pid'] == rows['fopdt'] == 'built-in'


def test_the_kit_passes_on_the_example_kinds():
    check_controller_kind('on_off', {'u_min': 0.0, 'u_max': 60.0, 'hysteresis': 1.0},
                          y0=20.0, r0=20.0)
    check_plant_kind('heater', u=30.0)


def test_lockstep_with_ros2_run_nodes_equals_the_in_process_loop(ros_env, tmp_path):
    scenario = effective_harness(load_scenario(SCENARIO), duration=120.0)
    started = []

    def ros2_run(node: str) -> list[str]:
        started.append(node)
        return ros2_argv('run', 'tank_control', f'{node}_node')

    ros = runner.run_scenario(scenario, tmp_path / 'ros', env=ros_env, node_command=ros2_run,
                              plots=False)
    ref = runner.run_scenario(scenario, tmp_path / 'ref', in_process=True, plots=False)
    assert {'plant', 'controller', 'reference'} <= set(started)
    assert ros.metrics['complete'], ros.metrics.get('reason')
    assert ros.metrics['controller']['parameters']['controller'] == 'on_off'
    assert len(ros.trace) == len(ref.trace) == 241
    for name, column in ref.trace.columns.items():
        np.testing.assert_allclose(ros.trace.columns[name], column, rtol=0, atol=1e-9,
                                   err_msg=name)
    u = np.asarray(ref.trace.columns['u.u'])
    assert set(np.unique(u)) == {0.0, 60.0}           # on/off: only its two outputs
    assert np.count_nonzero(np.diff(u)) >= 3           # and it switched


def test_a_sweep_on_two_workers_runs_the_example_kinds(ros_env, tmp_path):
    out = cli(ros_env, 'sweep', str(SCENARIO), '--grid', 'controller.hysteresis=0.5,2.0',
              '--grid', 'plant.deadband=0,10', '--workers', '2', '--duration', '100',
              '--out', str(tmp_path / 'sweep'), '--quiet')
    assert out.returncode == 0, out.stderr[-2000:]
    rows = list(csv.DictReader((tmp_path / 'sweep' / 'results.csv').open()))
    assert len(rows) == 4 and {r['status'] for r in rows} == {'ok'}
    switching = {(float(r['controller.hysteresis']), float(r['plant.deadband'])):
                 float(r['u.total_variation']) for r in rows}
    # a wider band switches less often
    assert switching[(2.0, 0.0)] < switching[(0.5, 0.0)]


def test_the_example_packages_own_tests_pass(ros_env):
    env = {**ros_env, 'PYTEST_DISABLE_PLUGIN_AUTOLOAD': '1'}
    done = subprocess.run([sys.executable, '-m', 'pytest', '-q', '-p', 'no:cacheprovider',
                           '-p', 'no:xdist', str(EXAMPLE / 'tests')], env=env, cwd=EXAMPLE,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout[-3000:]
    assert '3 passed' in done.stdout


def test_the_node_help_lists_the_installed_kinds(ros_env):
    done = subprocess.run([sys.executable, '-m', 'tank_control.nodes.controller_node', '--help'],
                          env=ros_env, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert 'fsa, on_off' in done.stdout              # the built-ins, then the plugin's


def test_the_kits_lockstep_check_on_the_example_scenario(ros_env, monkeypatch, tmp_path):
    """``check_controller_kind(..., scenario=)``: the contract with lockstep == in-process."""
    for name, value in ros_env.items():
        monkeypatch.setenv(name, value)
    report = check_controller_kind('on_off', {'u_min': 0.0, 'u_max': 60.0}, y0=20.0, r0=20.0,
                                   scenario=str(SCENARIO),
                                   scenario_overrides=['harness.duration=60.0'],
                                   out_dir=tmp_path)
    assert 'lockstep == in-process' in report.checked
    assert (tmp_path / 'lockstep' / 'trace.csv').is_file()
