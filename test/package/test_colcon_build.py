"""The package builds as a normal ament_python package in a colcon workspace."""
from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

from support import REPO


def test_colcon_build_installs_runnable_executables(tmp_path: Path, procs, ros_env, probe):
    colcon = Path(sys.executable).with_name('colcon')
    assert colcon.exists(), 'colcon is part of the test set-up (requirements-colcon.txt)'
    build = subprocess.run(
        [str(colcon), '--log-base', str(tmp_path / 'log'), 'build', '--base-paths', str(REPO),
         '--build-base', str(tmp_path / 'build'), '--install-base', str(tmp_path / 'install')],
        cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert build.returncode == 0, build.stdout + build.stderr

    prefix = tmp_path / 'install' / 'tank_control'
    for exe in ('plant_node', 'controller_node', 'reference_node'):
        assert (prefix / 'lib' / 'tank_control' / exe).is_file()
    assert (prefix / 'share' / 'ament_index' / 'resource_index' / 'packages' / 'tank_control').is_file()
    assert (prefix / 'share' / 'tank_control' / 'package.xml').is_file()

    # Run the built executable the way a ROS user does: source the workspace, start it.
    script = (f'source {tmp_path}/install/setup.bash && '
              f'exec {prefix}/lib/tank_control/plant_node')
    proc = procs.start('colcon_plant', [shutil.which('bash'), '-c', script], env=ros_env)
    assert probe.wait_for(lambda: 'plant' in probe.node.get_node_names(), timeout=60), proc.tail()
    assert procs.stop('colcon_plant') == 0, proc.tail()
