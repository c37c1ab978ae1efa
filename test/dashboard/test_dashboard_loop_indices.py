"""The loop monitor's indices per loop on the dashboard's faceplate, in a real browser (headless
Chromium) on a live loop over real DDS (docs/monitoring.md, "Live"): the aggressive loop of
config/scenarios/monitor_aggressive.yaml (plant, controller, reference, dashboard_node) paced at
20x real time. The faceplate's line under the loop shows the verdict, the Harris index with its
dead time, the oscillation's period and amplitude, the stiction index and the saturated, manual
and fail-safe times — the numbers of one of the summaries controller_node published on
``~/loop_performance``."""
from __future__ import annotations

import json
from decimal import ROUND_HALF_UP, Decimal
from pathlib import Path

import pytest
from selenium.common.exceptions import StaleElementReferenceException
from selenium.webdriver.support.ui import WebDriverWait
from std_msgs.msg import String
from support.browser import chromium_page, dashboard_url

from tank_control.nodes.messages import reliable_qos

WAIT = 90.0                  # s: a loaded 2-core machine; every wait ends at its event
SCENARIO = Path(__file__).resolve().parents[2] / 'config' / 'scenarios' / 'monitor_aggressive.yaml'
LINE = '[data-testid="faceplate-/controller"] [data-testid="indices-y"]'


@pytest.fixture
def browser():
    with chromium_page(1366, 768) as driver:
        yield driver


def shown(driver) -> dict[str, str]:
    return driver.execute_script(
        'const line = document.querySelector(arguments[0]); if (!line) return {};'
        'const out = {}; for (const s of line.querySelectorAll("[data-testid]"))'
        ' out[s.dataset.testid] = s.querySelector("b").textContent; return out;', LINE)


def g3(v: float) -> str:
    """3 significant digits, as controller_node sends them and the page writes them."""
    return f'{float(f"{v:.3g}"):g}'


def fixed(v: float, digits: int) -> str:
    """JavaScript's toFixed of the 3-significant-digit value sent (ties away from zero)."""
    exact = Decimal(float(f'{v:.3g}'))
    return str(exact.quantize(Decimal(1).scaleb(-digits), rounding=ROUND_HALF_UP))


def pct(v: float | None) -> str:
    return f'{fixed(v, 0)} %' if v is not None else '–'


def as_shown(r: dict) -> dict[str, str]:
    """A published summary as the faceplate writes it (loops.js)."""
    osc, st = r['oscillation'], r['stiction']
    return {
        'verdict': r['verdict'],
        # an early summary (too few samples yet) has no index: the page shows a dash
        'harris': (f'{fixed(r["harris_index"], 2)} (L {g3(r["dead_time"])} s)'
                   if r['harris_index'] is not None else '–'),
        'oscillation': (f'{g3(osc["period"])} s, amplitude {g3(osc["amplitude"])}'
                        if osc['detected'] else 'none'),
        'stiction': (f'{"suspected" if st["detected"] else "no"} (index {fixed(st["index"], 2)})'
                     if st['index'] is not None else 'not assessed'),
        'saturation': pct(r['saturation_pct']),
        'manual': pct(r['manual_pct']),
        'fail-safe': pct(r['fail_safe_pct']),
    }


def test_faceplate_shows_each_loops_indices(procs, ros_env, node_cmd, tmp_path, probe, browser):
    text = SCENARIO.read_text()
    assert text.count('real_time_factor: 0.0\n') == 1 and text.count('    u_max: 50.0\n') == 1
    params = tmp_path / 'aggressive.yaml'
    # paced so that the page follows; the monitor assesses from the start, every 5 s
    # (lockstep as the harness runs it: the plant is the clock)
    params.write_text('/**:\n  ros__parameters:\n    clock_mode: lockstep\n' + text.replace(
        'real_time_factor: 0.0\n', 'real_time_factor: 20.0\n').replace(
        '    u_max: 50.0\n', '    u_max: 50.0\n    monitor.settle_time: 0.0\n'
                            '    monitor.period: 5.0\n'))
    reports: list[dict] = []
    probe.node.create_subscription(String, '/controller/loop_performance',
                                   lambda m: reports.append(json.loads(m.data)),
                                   reliable_qos(10, latched=True))
    for module in ('plant_node', 'controller_node', 'reference_node'):
        procs.start(module, node_cmd(module, '--params-file', str(params)), env=ros_env)
    browser.get(dashboard_url(procs.start('dashboard', node_cmd('dashboard_node', '-p', 'port:=0'),
                                          env=ros_env)))
    wait = WebDriverWait(browser, WAIT, ignored_exceptions=(StaleElementReferenceException,))
    # an oscillation with its period and a Harris index with the dead time of the file's model
    wait.until(lambda d: shown(d).get('oscillation', 'none') != 'none'
               and shown(d).get('harris', '–') != '–', 'no indices shown')
    assert probe.wait_for(lambda: len(reports) > 0, WAIT)
    line = shown(browser)
    browser.save_screenshot(str(tmp_path / 'faceplate-indices.png'))
    assert line['harris'].endswith('(L 2 s)') and line['verdict'].startswith('retune (oscillating')
    # the numbers are those of a summary the node published (the page shows the one its
    # latest /diagnostics carried)
    assert probe.wait_for(lambda: any(as_shown(r) == line for r in reports), WAIT), \
        (line, [as_shown(r) for r in reports[-3:]])
