"""dashboard_node as a process: serves the page and every asset itself (no network), stops
cleanly on SIGINT and SIGTERM, and a port it cannot listen on stops it with one line."""
from __future__ import annotations

import re
import signal
import socket
import subprocess
import urllib.request

import pytest
from support.browser import base_url, dashboard_url

from tank_control.dashboard.server import load_assets


def fetch(url: str) -> tuple[int, str, bytes]:
    with urllib.request.urlopen(url, timeout=30) as response:
        return response.status, response.headers.get('Content-Type', ''), response.read()


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_serves_the_page_and_its_assets_and_stops_cleanly(sig, procs, ros_env, node_cmd):
    proc = procs.start('dashboard', node_cmd('dashboard_node', '-p', 'port:=0'), env=ros_env)
    url = dashboard_url(proc)
    status, kind, page = fetch(url)
    assert status == 200 and kind.startswith('text/html')
    # every script and stylesheet the page names is served by the node (nothing remote)
    linked = [link for link in re.findall(rb'(?:src|href)="([^"]+)"', page)
              if link != b'/runs']                   # the runs page: test_dashboard_runs.py
    assert linked and all(link.startswith(b'/static/') for link in linked)
    for link in linked:
        status, _, body = fetch(base_url(url) + link.decode().lstrip('/'))
        assert status == 200 and body == load_assets()[link.decode()][0]
    proc.popen.send_signal(sig)
    assert proc.popen.wait(timeout=30) == 0, proc.tail()


def test_a_port_in_use_stops_the_node_with_one_line(ros_env, node_cmd):
    with socket.socket() as busy:
        busy.bind(('127.0.0.1', 0))
        busy.listen()
        port = busy.getsockname()[1]
        run = subprocess.run(node_cmd('dashboard_node', '-p', f'port:={port}'), env=ros_env,
                             capture_output=True, text=True, timeout=120)
    assert run.returncode == 2
    lines = run.stderr.strip().splitlines()
    assert lines[-1].startswith('dashboard_node: host/port: cannot listen on 127.0.0.1:'
                                f'{port}'), run.stderr
    assert 'Traceback' not in run.stderr
