"""The runs page of dashboard_node (``/runs``, ``runs_dir``): runs made by
``tank-control run ... --in-process --out <runs_dir>/<name>`` are listed with their scenario,
title, complete flag and key metrics as their metrics.json says, their pictures are served
byte for byte, the compare view puts the selected runs' metrics side by side, and no path
reaches a file outside ``runs_dir``."""
from __future__ import annotations

import http.client
import json
import math
import os
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path

import pytest
from selenium.webdriver.common.by import By
from selenium.webdriver.support.ui import WebDriverWait
from support import CONFIG
from support.browser import base_url, chromium_page, dashboard_url

from tank_control.dashboard.runs import list_runs, run_file
from tank_control.harness import cli

WAIT = 60.0
SECRET = 'not for the page'
RUNS = {'zn': 'fopdt_zn.yaml', 'ipdt': 'ipdt_pid.yaml'}


@pytest.fixture(scope='module')
def runs_dir(tmp_path_factory) -> Path:
    """Two complete runs, a folder with a broken metrics.json, a file beside runs_dir and a
    symbolic link inside it pointing there."""
    base = tmp_path_factory.mktemp('runs_page')
    root = base / 'runs'
    for name, scenario in RUNS.items():             # the command, in this process
        assert cli.main(['run', str(CONFIG / scenario), '--in-process', '--quiet', '--out',
                         str(root / name)]) == 0
    (root / 'broken').mkdir()
    (root / 'broken' / 'metrics.json').write_text('{"scenario": ')
    (base / 'secret.txt').write_text(SECRET)
    os.symlink(base / 'secret.txt', root / 'zn' / 'link.txt')
    return root


def metrics_of(root: Path, name: str) -> dict:
    return json.loads((root / name / 'metrics.json').read_text())


def fetch(url: str) -> tuple[int, str, bytes]:
    try:
        with urllib.request.urlopen(url, timeout=30) as response:
            return response.status, response.headers.get('Content-Type', ''), response.read()
    except urllib.error.HTTPError as err:
        return err.code, '', err.read()


def raw_get(url: str, path: str) -> tuple[int, bytes]:
    """GET ``path`` exactly as written (no client-side normalisation of ``..``)."""
    parts = urllib.parse.urlsplit(url)
    conn = http.client.HTTPConnection(parts.hostname, parts.port, timeout=30)
    try:
        conn.putrequest('GET', path, skip_accept_encoding=True)
        conn.endheaders()
        response = conn.getresponse()
        return response.status, response.read()
    finally:
        conn.close()


def test_run_file_stays_inside_runs_dir(runs_dir):
    assert run_file(str(runs_dir), 'zn/plot.png') == runs_dir / 'zn' / 'plot.png'
    for bad in ('../secret.txt', 'zn/../../secret.txt', str(runs_dir.parent / 'secret.txt'),
                'zn/link.txt', '', '.', 'zn', 'zn/missing.png', 'zn/\x00plot.png'):
        assert run_file(str(runs_dir), bad) is None, bad
    assert run_file('', 'zn/plot.png') is None


def test_the_list_says_what_metrics_json_says(runs_dir):
    table = list_runs(str(runs_dir))
    rows = {row['name']: row for row in table['runs']}
    assert set(rows) == {'zn', 'ipdt', 'broken'}
    for name in RUNS:
        metrics = metrics_of(runs_dir, name)
        row = rows[name]
        assert (row['scenario'], row['title'], row['complete']) == (
            metrics['scenario'], metrics['title'], metrics['complete'])
        assert row['complete'] is True
        assert row['metrics']['y.iae'] == metrics['outputs']['y']['iae']
        assert row['verdicts'] == {'y': metrics['loop_performance']['y']['verdict']}
        assert row['files'] == ['plot.png', 'analysis.png']
    assert 'broken/metrics.json: not readable' in rows['broken']['error']
    assert 'runs_dir:=' in list_runs('')['hint']
    assert 'is not a folder' in list_runs(str(runs_dir / 'nothing'))['hint']


@pytest.fixture
def dashboard(runs_dir, procs, ros_env, node_cmd):
    dash = procs.start('dashboard', node_cmd('dashboard_node', '-p', 'port:=0', '-p',
                                             f'runs_dir:={runs_dir}'), env=ros_env)
    return base_url(dashboard_url(dash))


def test_files_are_served_read_only_and_only_from_runs_dir(dashboard, runs_dir):
    picture = (runs_dir / 'zn' / 'plot.png').read_bytes()
    status, kind, body = fetch(dashboard + 'runs/file/zn/plot.png')
    assert status == 200 and kind == 'image/png' and body == picture
    for path in ('/runs/file/../secret.txt', '/runs/file/..%2Fsecret.txt',
                 '/runs/file/%2E%2E/secret.txt', '/runs/file/zn/..%2F..%2Fsecret.txt',
                 '/runs/file/zn/%2e%2e/%2e%2e/secret.txt',
                 '/runs/file/' + urllib.parse.quote(str(runs_dir.parent / 'secret.txt'),
                                                    safe=''),
                 '/runs/file//' + str(runs_dir.parent / 'secret.txt').lstrip('/'),
                 '/runs/file/zn/link.txt', '/runs/file/zn/%00'):
        status, body = raw_get(dashboard, path)
        assert status in (400, 404), (path, status)
        assert SECRET.encode() not in body, path
    # read-only: nothing but GET (and HEAD) is answered
    request = urllib.request.Request(dashboard + 'runs/file/zn/plot.png', data=b'x',
                                     method='PUT')
    with pytest.raises(urllib.error.HTTPError) as refused:
        urllib.request.urlopen(request, timeout=30)
    assert refused.value.code == 405
    assert (runs_dir / 'zn' / 'plot.png').read_bytes() == picture


def shown(value: float) -> float:
    """The page's display: 4 significant digits."""
    return float(f'{value:.4g}')


def test_the_runs_page_lists_links_and_compares(dashboard, runs_dir):
    with chromium_page(height=1400) as driver:
        driver.get(dashboard + 'runs')
        wait = WebDriverWait(driver, WAIT)
        wait.until(lambda d: len(d.find_elements(By.CSS_SELECTOR, '#runs tr[data-run]')) == 3)
        for name in RUNS:
            metrics = metrics_of(runs_dir, name)
            row = driver.find_element(By.CSS_SELECTOR, f'#runs tr[data-run="{name}"]')
            cells = row.find_elements(By.TAG_NAME, 'td')
            assert cells[1].text == name and cells[2].text == metrics['scenario']
            assert cells[4].text == 'yes'
            iae = row.find_element(By.CSS_SELECTOR, '.metric[data-metric="y.iae"]').text
            assert float(iae.split()[-1]) == shown(metrics['outputs']['y']['iae'])
            verdict = row.find_element(By.CSS_SELECTOR, '.verdict[data-loop="y"]').text
            assert verdict == f"y: {metrics['loop_performance']['y']['verdict']}"
            links = row.find_elements(By.CSS_SELECTOR, 'a.picture')
            assert [a.text for a in links] == ['plot.png', 'analysis.png']
            for a in links:
                status, kind, body = fetch(a.get_attribute('href'))
                assert status == 200 and kind == 'image/png'
                assert body == (runs_dir / name / a.text).read_bytes()
        broken = driver.find_element(By.CSS_SELECTOR, '#runs tr[data-run="broken"]').text
        assert 'not readable' in broken
        # compare: the two runs' metrics side by side
        assert not driver.find_element(By.ID, 'compare').is_enabled()
        for name in RUNS:
            driver.find_element(By.CSS_SELECTOR, f'input[data-run="{name}"]').click()
        driver.find_element(By.ID, 'compare').click()
        wait.until(lambda d: d.find_element(By.ID, 'comparison').is_displayed())
        for metric, path in (('y.iae', ('outputs', 'y', 'iae')),
                             ('u.max', ('inputs', 'u', 'max'))):
            row = driver.find_element(By.CSS_SELECTOR, f'#compare-table tr[data-metric="{metric}"]')
            for name in RUNS:
                value = metrics_of(runs_dir, name)
                for key in path:
                    value = value[key]
                cell = row.find_element(By.CSS_SELECTOR, f'td[data-run="{name}"]').text
                assert float(cell) == shown(value), (metric, name)
        gm = driver.find_element(By.CSS_SELECTOR,
                                 '#compare-table tr[data-metric="loop.gain_margin"]')
        values = [float(c.text) for c in gm.find_elements(By.CSS_SELECTOR, 'td[data-run]')]
        assert len(values) == 2 and all(math.isfinite(v) for v in values)


def test_without_runs_dir_the_page_says_how_to_set_it(procs, ros_env, node_cmd):
    dash = procs.start('dashboard', node_cmd('dashboard_node', '-p', 'port:=0'), env=ros_env)
    status, kind, body = fetch(base_url(dashboard_url(dash)) + 'api/runs')
    table = json.loads(body)
    assert status == 200 and table['runs'] == [] and 'runs_dir:=' in table['hint']
