"""``make demo`` (the main job): its default path, cut short with ``--duration``.

The default scenario is the mixing tank of [Michalski2021] under the constrained, offset-free MPCS-QP
with the default horizons and the document's own constraints ([Michalski2021] §6: 0 <= F <= 100 cm³/s, |ΔF| <= 0.2 cm³/s per
sample), run in lockstep over ROS 2; the demo prints the metrics table and the paths of
plot, trace and recording, and the recorded trace equals the in-process loop to 1e-9.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

from tank_control import demo
from tank_control.core import params_file
from tank_control.core.trace import Trace
from tank_control.harness.runner import run

DURATION = 150.0    # [s] covers the take-over at the operating point and the h step at 100 s


def test_default_scenario_is_mpcs_qp_within_the_documents_constraints():
    path = demo.config_dir() / demo.DEFAULT_SCENARIO
    assert path.name == 'tank_mpcs_qp.yaml'
    ctrl = params_file.read(path)['controller']
    assert (ctrl['controller'], ctrl['mpcs.solver']) == ('mpcs', 'qp')
    # the default horizons (no warning), [Michalski2021]'s λ 0.5 and constraints 0 <= u <= 100, |Δu| <= 0.2
    from tank_control.core.control.mpcs import MpcsConfig
    c = MpcsConfig()
    assert (ctrl['mpcs.horizon'], ctrl['mpcs.control_horizon'], ctrl['mpcs.block']) == (
        c.horizon, c.control_horizon, c.block)
    assert ctrl['mpcs.lambda'] == [0.5]
    assert ctrl['mpcs.u_min'] == [0.0, 0.0] and ctrl['mpcs.u_max'] == [100.0, 100.0]
    assert ctrl['mpcs.du_max'] == [0.2, 0.2]


def test_demo_default_runs_in_lockstep_over_ros_and_prints_table_and_paths(tmp_path, ros_env):
    out = tmp_path / 'demo'
    done = subprocess.run([sys.executable, '-m', 'tank_control.demo', '--out', str(out),
                           '--duration', str(DURATION)], env=ros_env, capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    text = done.stdout
    assert 'tank_mpcs_qp.yaml, lockstep over ROS 2' in text
    assert 'initial_output (F_H 14, F_Cin 37)' in text
    assert '| tank_mpcs_qp | h |' in text and '| tank_mpcs_qp | T_out |' in text
    assert text.count('constraint violations 0') == 2 and 'controller warning' not in text
    for label, name in (('plot', 'plot.png'), ('trace', 'trace.csv'), ('recording', 'run.mcap')):
        line = next(ln for ln in text.splitlines() if ln.startswith(f'{label}:'))
        assert Path(line.split(':', 1)[1].strip()) == out / name
        assert (out / name).stat().st_size > 0

    # the ROS run is the in-process loop (core/loop.py), tick for tick
    ros = Trace.read_csv(out / 'trace.csv')
    ref = Trace.read_csv(run(demo.config_dir() / demo.DEFAULT_SCENARIO, tmp_path / 'ref',
                       duration=DURATION, in_process=True, plots=False).files['trace'])
    assert len(ros) == len(ref) == int(DURATION) + 1
    for name in ref.columns:
        np.testing.assert_allclose(ros.columns[name], ref.columns[name], rtol=0, atol=1e-9,
                                   err_msg=name)
    # the h step at 100 s really happened and MPCS moved within |Δu| <= 0.2 per sample
    assert ros.columns['r.h'][-1] == 90.0 and ros.columns['y.h'][-1] > 81.5
    u = np.column_stack([ros.columns['u.F_H'], ros.columns['u.F_Cin']])
    assert np.all(np.abs(np.diff(u, axis=0)) <= 0.2 + 1e-9)
