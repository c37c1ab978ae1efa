"""A lockstep run with the dashboard attached (dashboard_node and a page in headless Chromium
watching it) equals the in-process run to 1e-9 on every signal: the dashboard only subscribes,
it cannot disturb the loop. And the page got every tick with the recorded values
(config/ipdt_pid.yaml at 2x real time, 20 ticks per wall second: the publishers keep the last 10
messages for a reader, so this leaves a starved dashboard process half a second; the rate the
dashboard sustains is measured by bench/bench_dashboard.py, not asserted here)."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
from selenium.webdriver.support.ui import WebDriverWait
from support import CONFIG
from support.browser import dashboard_url, headless_chromium

from tank_control.core.trace import Trace

SCENARIO = CONFIG / 'ipdt_pid.yaml'
DURATION = '20'        # s of plant time: 201 ticks of 0.1 s
RTF = '2'              # 20 ticks per wall second


def tank_control(*args: str, env) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, '-m', 'tank_control.harness.cli', *args], env=env,
                          capture_output=True, text=True, timeout=600)


def test_lockstep_with_the_dashboard_attached_equals_in_process(tmp_path, procs, ros_env,
                                                                node_cmd):
    dash = procs.start('dashboard', node_cmd('dashboard_node', '-p', 'port:=0'), env=ros_env)
    with headless_chromium() as page:
        page.get(dashboard_url(dash))
        WebDriverWait(page, 60).until(lambda d: d.execute_script(
            'return document.getElementById("connection").textContent') == 'live')
        ros = tank_control('run', str(SCENARIO), '--out', str(tmp_path / 'ros'), '--duration',
                           DURATION, '--rtf', RTF, '--quiet', env=ros_env)
        assert ros.returncode == 0, ros.stderr[-3000:]
        trace = Trace.read_csv(tmp_path / 'ros' / 'trace.csv')
        ticks = sorted(round(t * 10) for t in trace.t)
        # every tick of the run reaches the page (the last batch within one update period)
        script = ('const m = window.tankDashboard.topics.measurement;'
                  'return m ? m.t.map((t) => Math.round(t * 10)) : [];')
        WebDriverWait(page, 60).until(
            lambda d: set(ticks) <= set(d.execute_script(script)))
        assert page.execute_script('return window.tankDashboard.stats.lost') == 0
        # the values shown are the ones recorded (the plant may tick past the run's end)
        shown = page.execute_script('const m = window.tankDashboard.topics.measurement;'
                                    'return [m.t, m.ch.y];')
        by_tick = dict(zip((round(t * 10) for t in shown[0]), shown[1]))
        np.testing.assert_array_equal([by_tick[k] for k in ticks], trace.columns['y.y'])
    ref = tank_control('run', str(SCENARIO), '--out', str(tmp_path / 'ref'), '--duration',
                       DURATION, '--in-process', '--quiet', env=ros_env)
    assert ref.returncode == 0, ref.stderr[-3000:]
    expected = Trace.read_csv(tmp_path / 'ref' / 'trace.csv')
    assert list(trace.columns) == list(expected.columns) and len(trace) == len(expected) == 201
    for name in expected.columns:
        np.testing.assert_allclose(trace.columns[name], expected.columns[name], rtol=0,
                                   atol=1e-9, err_msg=name)
