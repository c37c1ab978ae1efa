"""The kit is a pytest plugin (entry point ``pytest11`` in setup.py) whose fixture runs a
scenario and returns its metrics; importing it loads no ROS package."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_the_packaging_registers_the_kit_as_a_pytest_plugin(tmp_path):
    done = subprocess.run([sys.executable, 'setup.py', '-q', 'egg_info', '--egg-base',
                           str(tmp_path)], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    text = (tmp_path / 'tank_control.egg-info' / 'entry_points.txt').read_text()
    assert '[pytest11]\ntank_control = tank_control.testing.plugin' in text


def test_the_fixture_runs_a_scenario_and_importing_the_kit_loads_no_ros(tmp_path):
    (tmp_path / 'test_user.py').write_text(f'''
import sys
def test_run(tank_control_run):
    assert 'rclpy' not in sys.modules
    metrics = tank_control_run({str(ROOT / 'config' / 'ipdt_pid.yaml')!r},
                               ['plant.dead_time=4.0'], duration=20.0)
    assert metrics['complete'] and metrics['mode'] == 'in_process'
    assert metrics['overrides'] == ['plant.dead_time=4.0']
    assert 'y' in metrics['outputs']
''')
    env = {**os.environ, 'PYTEST_DISABLE_PLUGIN_AUTOLOAD': '1', 'PYTHONPATH': str(ROOT)}
    done = subprocess.run([sys.executable, '-m', 'pytest', '-q', '-p', 'no:cacheprovider', '-p',
                           'tank_control.testing.plugin', str(tmp_path / 'test_user.py')],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-2000:]
    assert '1 passed' in done.stdout
