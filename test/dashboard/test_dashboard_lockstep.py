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


def _free_port() -> int:
    import socket
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def _running_with(text: str) -> list[int]:
    from pathlib import Path
    found = []
    for entry in Path('/proc').iterdir():
        if entry.name.isdigit():
            try:
                cmdline = (entry / 'cmdline').read_bytes().replace(b'\0', b' ').decode()
            except OSError:
                continue
            if text in cmdline:
                found.append(int(entry.name))
    return found


def test_tank_control_run_dashboard_serves_the_run_and_stops_with_it(tmp_path, procs, ros_env):
    """`tank-control run ... --dashboard PORT` starts dashboard_node for the run: the page shows
    the run's measurement while it goes, and the node ends with the run."""
    import time
    port = _free_port()
    out = tmp_path / 'run'
    harness = procs.start('harness', [sys.executable, '-m', 'tank_control.harness.cli', 'run',
                                      str(SCENARIO), '--out', str(out), '--duration', '40',
                                      '--rtf', '4', '--quiet', '--dashboard', str(port)],
                          env=ros_env)
    log = out / 'logs' / 'dashboard.log'
    deadline = time.monotonic() + 120
    while not (log.exists() and 'dashboard at' in log.read_text(errors='replace')):
        assert harness.returncode is None and time.monotonic() < deadline, harness.tail()
        time.sleep(0.1)            # polling a log file: no event to wait on
    with headless_chromium() as page:
        page.get(f'http://127.0.0.1:{port}/')
        script = ('const m = window.tankDashboard && window.tankDashboard.topics.measurement;'
                  'return m ? m.t.length : 0;')
        WebDriverWait(page, 60).until(lambda d: d.execute_script(script) >= 20)
    assert harness.popen.wait(timeout=300) == 0, harness.tail()
    assert _running_with(f'port:={port}') == []
    assert len(Trace.read_csv(out / 'trace.csv')) == 401


def test_dashboard_with_an_in_process_run_is_refused(tmp_path):
    import pytest

    from tank_control.harness.runner import ScenarioError, run
    with pytest.raises(ScenarioError, match='--dashboard watches the nodes of a ROS run'):
        run(SCENARIO, tmp_path / 'x', in_process=True, dashboard=8080)
    assert not (tmp_path / 'x').exists()
