"""A lockstep run with the dashboard attached (dashboard_node and a page in headless Chromium
watching it) equals the in-process run to 1e-9 on every signal: the dashboard only subscribes,
it cannot disturb the loop — not even when its process is frozen for seconds (SIGSTOP). And the
page never hides a gap: from the first tick it received on, every tick of the run is either
shown with the recorded value or counted as "missed" (the middleware's message-lost count: the
publishers keep the last 10 messages for a reader that lags). config/ipdt_pid.yaml at 2x real time, 20 ticks per wall
second; the rate the dashboard sustains without loss is measured by bench/bench_dashboard.py."""
from __future__ import annotations

import os
import signal
import subprocess
import sys

import numpy as np
from selenium.common.exceptions import TimeoutException
from selenium.webdriver.support.ui import WebDriverWait
from support import CONFIG
from support.browser import chromium_page, dashboard_url
from support.ports import free_port
from support.procfs import processes_with

from tank_control.core.trace import Trace

SCENARIO = CONFIG / 'ipdt_pid.yaml'
DURATION = '20'        # s of plant time: 201 ticks of 0.1 s
TICKS = 201
RTF = '2'              # 20 ticks per wall second
FROZEN = 3.0           # s the dashboard process is stopped: 60 ticks, beyond the writers' 10

SHOWN = ('const m = window.tankDashboard.topics.measurement;'
         'return m ? [m.t.map((t) => Math.round(t * 10)), m.ch.y] : [[], []];')
MISSED = 'return window.tankDashboard.stats.missed.measurement || 0;'


def tank_control(*args: str, env) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, '-m', 'tank_control.harness.cli', *args], env=env,
                          capture_output=True, text=True, timeout=600)


def test_lockstep_with_the_dashboard_attached_equals_in_process(tmp_path, procs, ros_env,
                                                                node_cmd):
    import time
    dash = procs.start('dashboard', node_cmd('dashboard_node', '-p', 'port:=0'), env=ros_env)
    with chromium_page() as page:
        page.get(dashboard_url(dash))
        WebDriverWait(page, 60).until(lambda d: d.execute_script(
            'return document.getElementById("connection").textContent') == 'live')
        run = procs.start('harness', [sys.executable, '-m', 'tank_control.harness.cli', 'run',
                                      str(SCENARIO), '--out', str(tmp_path / 'ros'),
                                      '--duration', DURATION, '--rtf', RTF, '--quiet',
                                      '--no-plots'], env=ros_env)
        # the page shows the run, then the dashboard process is frozen for FROZEN s
        WebDriverWait(page, 120).until(lambda d: len(d.execute_script(SHOWN)[0]) >= 20)
        os.kill(dash.popen.pid, signal.SIGSTOP)
        try:
            time.sleep(FROZEN)     # the freeze itself is what is tested: a duration, no event
        finally:
            os.kill(dash.popen.pid, signal.SIGCONT)
        assert run.popen.wait(timeout=300) == 0, run.tail()
        trace = Trace.read_csv(tmp_path / 'ros' / 'trace.csv')
        ticks = [round(t * 10) for t in trace.t]
        assert ticks == list(range(TICKS))

        def accounting(d) -> tuple[int, int, int]:
            """(first tick shown, ticks shown from it on, missed): a subscriber that matches
            the plant's publisher after the first ticks never gets those (volatile QoS, not
            a loss); from the first tick it got on, every tick is shown or counted."""
            shown = {k for k in d.execute_script(SHOWN)[0] if k < TICKS}
            return min(shown, default=TICKS), len(shown), d.execute_script(MISSED)

        def accounted(d) -> bool:
            first, shown, missed = accounting(d)
            return shown + missed >= TICKS - first
        # every tick is shown or counted as missed (the last batch within an update period)
        try:
            WebDriverWait(page, 60).until(accounted)
        except TimeoutException:
            first, shown, missed = accounting(page)
            raise AssertionError(f'from tick {first} on, {shown} shown + {missed} missed < '
                                 f'{TICKS - first}') from None
        shown_t, shown_y = page.execute_script(SHOWN)
        missed = page.execute_script(MISSED)
        assert page.execute_script('return window.tankDashboard.stats.lost') == 0
        assert missed > 0, 'the frozen dashboard lost nothing: the freeze did not happen'
        assert int(page.find_element('id', 'missed').text) >= missed
        # the values shown are the ones recorded (the plant may tick past the run's end)
        by_tick = dict(zip(shown_t, shown_y))
        recorded = dict(zip(ticks, trace.columns['y.y']))
        assert {k: by_tick[k] for k in by_tick if k < TICKS} == {
            k: recorded[k] for k in by_tick if k < TICKS}
        print(f'\n[dashboard frozen {FROZEN} s] first tick shown {min(by_tick)}, shown '
              f'{sum(k < TICKS for k in by_tick)} of {TICKS} ticks, missed (message lost) '
              f'{missed}')
    ref = tank_control('run', str(SCENARIO), '--out', str(tmp_path / 'ref'), '--duration',
                       DURATION, '--in-process', '--quiet', env=ros_env)
    assert ref.returncode == 0, ref.stderr[-3000:]
    expected = Trace.read_csv(tmp_path / 'ref' / 'trace.csv')
    assert list(trace.columns) == list(expected.columns) and len(trace) == len(expected) == TICKS
    for name in expected.columns:
        np.testing.assert_allclose(trace.columns[name], expected.columns[name], rtol=0,
                                   atol=1e-9, err_msg=name)


def test_tank_control_run_dashboard_serves_the_run_and_stops_with_it(tmp_path, procs, ros_env):
    """`tank-control run ... --dashboard PORT` starts dashboard_node for the run: the page shows
    the run's measurement while it goes, and the node ends with the run."""
    import time
    port = free_port()
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
    with chromium_page() as page:
        page.get(f'http://127.0.0.1:{port}/')
        script = ('const m = window.tankDashboard && window.tankDashboard.topics.measurement;'
                  'return m ? m.t.length : 0;')
        WebDriverWait(page, 60).until(lambda d: d.execute_script(script) >= 20)
    assert harness.popen.wait(timeout=300) == 0, harness.tail()
    # the URL the harness printed carries the token the dashboard logged (writes need it)
    printed = harness.log_path.read_text(errors='replace')
    token = printed.split(f'dashboard: http://127.0.0.1:{port}/?token=', 1)[1].split()[0]
    assert f'dashboard at http://127.0.0.1:{port}/?token={token} ' in log.read_text()
    assert processes_with(f'port:={port}') == []
    assert len(Trace.read_csv(out / 'trace.csv')) == 401


def test_dashboard_with_an_in_process_run_is_refused(tmp_path):
    import pytest

    from tank_control.harness.runner import ScenarioError, run
    with pytest.raises(ScenarioError, match='--dashboard watches the nodes of a ROS run'):
        run(SCENARIO, tmp_path / 'x', in_process=True, dashboard=8080)
    assert not (tmp_path / 'x').exists()
