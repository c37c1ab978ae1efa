"""The dashboard in a real browser (headless Chromium) on a live loop over real DDS: plant,
relay-autotune controller and reference of config/fopdt_autotune.yaml in lockstep at 10x real
time, dashboard_node beside them. The page shows growing trends, edits reach the node through
its set_parameters service, a refusal shows the node's own reason, a change made elsewhere
appears in the page, and a command button calls the controller's Trigger service."""
from __future__ import annotations

import math

import pytest
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.srv import GetParameters, SetParameters
from rclpy.parameter import Parameter, parameter_value_to_python
from selenium.common.exceptions import StaleElementReferenceException
from selenium.webdriver.common.by import By
from selenium.webdriver.common.keys import Keys
from selenium.webdriver.support.ui import WebDriverWait
from support import CONFIG
from support.browser import chromium_page, dashboard_url
from support.ros2cli import ros2

SCENARIO = CONFIG / 'fopdt_autotune.yaml'
WAIT = 60.0          # s: a loaded 2-core machine; every wait ends at its event


@pytest.fixture
def live_loop(procs, ros_env, node_cmd, tmp_path):
    """The three nodes of the scenario (the test starts the auto-tuner itself) and the
    dashboard on a free port; returns the dashboard's URL."""
    text = SCENARIO.read_text()
    assert 'autotune.start_time: 0.0 ' in text  # the file waits for a command, as the README's user
    params = tmp_path / 'fopdt_autotune_10x.yaml'
    paced = 'real_time_factor: 1.0 '           # the file's pace for hand-started nodes
    assert paced in text
    params.write_text(text.replace(paced, 'real_time_factor: 10.0 '))    # the test: 10x
    for module in ('plant_node', 'controller_node', 'reference_node'):
        procs.start(module, node_cmd(module, '--params-file', str(params)), env=ros_env)
    dash = procs.start('dashboard', node_cmd('dashboard_node', '-p', 'port:=0'), env=ros_env)
    return dashboard_url(dash)


@pytest.fixture
def page(live_loop):
    with chromium_page() as driver:
        driver.get(live_loop)
        yield driver


def call(probe, srv, name, request):
    client = probe.node.create_client(srv, name)
    try:
        assert probe.wait_for(client.service_is_ready, WAIT), f'{name} not available'
        future = client.call_async(request)
        assert probe.wait_for(future.done, WAIT), f'{name} did not answer'
        return future.result()
    finally:
        probe.node.destroy_client(client)


def controller_param(probe, name):
    response = call(probe, GetParameters, '/controller/get_parameters',
                    GetParameters.Request(names=[name]))
    return parameter_value_to_python(response.values[0])


def param_input(driver, name, node='/controller'):
    return driver.find_element(By.CSS_SELECTOR,
                               f'input[data-node="{node}"][data-param="{name}"]')


def reason_text(driver, name, node='/controller'):
    return driver.find_element(By.CSS_SELECTOR,
                               f'.reason[data-node="{node}"][data-param="{name}"]').text


def type_into(driver, name, text):
    """Type into a controller's parameter and apply it in the confirmation the page asks
    (a write that changes a controller)."""
    box = param_input(driver, name)
    box.click()
    box.send_keys(Keys.CONTROL, 'a')
    box.send_keys(text, Keys.ENTER)
    WebDriverWait(driver, WAIT).until(lambda d: d.find_element(By.ID, 'confirm').is_displayed())
    driver.find_element(By.ID, 'confirm-apply').click()


def set_window(driver, seconds):
    box = driver.find_element(By.ID, 'window')
    box.click()
    box.send_keys(Keys.CONTROL, 'a')
    box.send_keys(seconds, Keys.ENTER)


def points(driver, chart):
    found = driver.find_elements(By.CSS_SELECTOR, f'.chart[data-chart="{chart}"]')
    return int(found[0].get_attribute('data-points')) if found else 0


def test_trends_grow_with_live_data_and_show_the_input_limits(page):
    # the page re-renders a chart (its legend too) as data and limits come: an element found
    # a moment ago may be gone when it is read, so each poll finds it again (CI once: stale)
    wait = WebDriverWait(page, WAIT, ignored_exceptions=(StaleElementReferenceException,))
    wait.until(lambda d: d.find_element(By.ID, 'connection').text == 'live')
    set_window(page, '3600')          # longer than the test: every sample stays in view
    wait.until(lambda d: points(d, 'y-y') > 0 and points(d, 'u-u') > 0)
    before = points(page, 'y-y'), points(page, 'u-u')
    wait.until(lambda d: points(d, 'y-y') > before[0] and points(d, 'u-u') > before[1])
    # measurement and setpoint in one chart, the input with the controller's u_min/u_max
    wait.until(lambda d: all(label in d.find_element(
        By.CSS_SELECTOR, '.chart[data-chart="y-y"] .u-legend').text
        for label in ('y measured', 'y setpoint')))
    wait.until(lambda d: 'max' in d.find_element(
        By.CSS_SELECTOR, '.chart[data-chart="u-u"] .u-legend').text)
    stats = page.execute_script('return window.tankDashboard.stats')
    assert stats['lost'] == 0 and stats['received'] > 0
    # every measurement the page holds is on the plant's 0.1 s grid, in order
    times = page.execute_script('return window.tankDashboard.topics.measurement.t')
    assert times == sorted(times)
    assert all(abs(t * 10 - round(t * 10)) < 1e-6 for t in times)
    # a 5 s window holds the last 5 s: 50 ticks of 0.1 s (51 with both ends)
    set_window(page, '5')
    wait.until(lambda d: 45 <= points(d, 'y-y') <= 51)
    # pause holds the plot, resume goes on
    page.find_element(By.ID, 'pause').click()
    held = page.execute_script('return window.tankDashboard.stats.frames')
    received = page.execute_script('return window.tankDashboard.stats.received')
    wait.until(lambda d: d.execute_script('return window.tankDashboard.stats.received')
               > received + 50)
    assert page.execute_script('return window.tankDashboard.stats.frames') == held
    page.find_element(By.ID, 'pause').click()
    wait.until(lambda d: d.execute_script('return window.tankDashboard.stats.frames') > held)


def test_an_edit_reaches_the_node_and_a_refusal_shows_its_reason(page, probe, ros_env):
    wait = WebDriverWait(page, WAIT)
    wait.until(lambda d: d.find_elements(By.CSS_SELECTOR,
                                         'input[data-node="/controller"][data-param="kp"]'))
    type_into(page, 'kp', '25')
    wait.until(lambda d: 'pending' not in param_input(d, 'kp').get_attribute('class'))
    assert reason_text(page, 'kp') == ''
    assert controller_param(probe, 'kp') == 25.0
    rows = '#audit-rows tr[data-node="/controller"][data-param="kp"] .audit-source'
    wait.until(lambda d: {'set_parameters service', 'dashboard /dashboard (page at 127.0.0.1)'}
               <= {e.text for e in d.find_elements(By.CSS_SELECTOR, rows)})
    got = ros2(ros_env, 'param', 'get', '/controller', 'kp')
    assert got.stdout.strip() == 'Double value is: 25.0', got.stderr

    # refused: the node's own reason, as its set_parameters service gives it to anyone
    refused = call(probe, SetParameters, '/controller/set_parameters', SetParameters.Request(
        parameters=[Parameter('kp', value=-1.0).to_parameter_msg()])).results[0]
    assert not refused.successful and refused.reason
    type_into(page, 'kp', '-1')
    wait.until(lambda d: refused.reason in reason_text(d, 'kp'))
    typed = call(probe, SetParameters, '/controller/set_parameters', SetParameters.Request(
        parameters=[ParameterMsg(name='kp', value=Parameter('kp', value='abc')
                                 .to_parameter_msg().value)])).results[0]
    assert not typed.successful and 'kp' in typed.reason
    type_into(page, 'kp', 'abc')
    wait.until(lambda d: typed.reason in reason_text(d, 'kp'))
    assert controller_param(probe, 'kp') == 25.0
    wait.until(lambda d: param_input(d, 'kp').get_attribute('value') == '25')

    # changed elsewhere (`ros2 param set`): the page follows
    done = ros2(ros_env, 'param', 'set', '/controller', 'ti', '15.5')
    assert done.returncode == 0, done.stderr
    wait.until(lambda d: param_input(d, 'ti').get_attribute('value') == '15.5')


def test_a_command_button_starts_the_autotuner_and_its_state_is_shown(page, probe):
    wait = WebDriverWait(page, WAIT)
    selector = 'button[data-node="/controller"][data-command="start_autotune"]'
    wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, selector))
    state = '.state[data-node="/controller"][data-topic="/controller/autotune_state"]'
    wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, state))
    assert page.find_element(By.CSS_SELECTOR, state).text == 'idle'
    page.find_element(By.CSS_SELECTOR, selector).click()
    result = ('.command-result[data-node="/controller"]'
              '[data-command="start_autotune"]')
    wait.until(lambda d: d.find_element(By.CSS_SELECTOR, result).text.startswith('ok'))
    wait.until(lambda d: d.find_element(By.CSS_SELECTOR, state).text != 'idle')
    assert controller_param(probe, 'autotune.state') != 'idle'
    # the abort button ends the test: the state shown follows the node's
    page.find_element(By.CSS_SELECTOR, selector.replace('start_autotune', 'abort_autotune')).click()
    wait.until(lambda d: d.find_element(By.CSS_SELECTOR, state).text == 'aborted')
    assert controller_param(probe, 'autotune.state') == 'aborted'
    # the state history is marked on the trends at the loop time of each change
    marks = 'return window.tankDashboard.marks.filter((m) => m.machine === "autotune");'
    wait.until(lambda d: [m['label'] for m in d.execute_script(marks)][-1:] == ['aborted'])
    state_time = controller_param(probe, 'autotune.state_time')
    wait.until(lambda d: d.execute_script(marks)[-1]['t'] == state_time)
    # the audit trail names the auto-tuner and the command as the source of its state changes
    rows = '#audit-rows tr[data-node="/controller"][data-param="autotune.state"]'
    wait.until(lambda d: any(r.find_element(By.CSS_SELECTOR, '.audit-change').text.endswith(
        '→ aborted') and r.find_element(By.CSS_SELECTOR, '.audit-source').text
        == 'controller relay_autotune, command /controller/abort_autotune'
        for r in d.find_elements(By.CSS_SELECTOR, rows)))
    shown = page.execute_script(marks)
    # the test's states before the abort (entered by the command: marked at once, moved to
    # their state_time at the next sample if there was one)
    assert len(shown) >= 2 and shown[0]['label'] in ('settling', 'relay', 'measuring')
    assert [m['t'] for m in shown] == sorted(m['t'] for m in shown)


def expected_margins(kp):
    """The analysis functions on the scenario's plant model and controller settings with
    ``kp``: ``loop_report`` (Nyquist with the exact delay, margins, Ms) — what
    ``tank-control analyze`` prints for the same parameters."""
    from dataclasses import replace

    from tank_control.core import scenario as core_scenario
    from tank_control.core.analysis.robustness import loop_report
    from tank_control.harness.scenario_file import load_scenario
    sections = load_scenario(SCENARIO).sections
    plant = core_scenario.plant_setup(core_scenario.node_values(sections, 'plant'))
    model = plant.kind.linear(plant.model)
    config = core_scenario.controller_setup(
        core_scenario.node_values(sections, 'controller')).settings.config
    return loop_report(model, replace(config, kp=kp))


def shown_margins(driver):
    cells = driver.find_elements(By.CSS_SELECTOR, '#margins td.margin[data-case="0"]')
    return {c.get_attribute('data-margin'): c.text for c in cells}


def agrees(text, value, digits):
    """``text`` is ``value`` rounded to ``digits`` significant digits (the page's display)."""
    shown = float(text)
    scale = 10 ** (math.floor(math.log10(abs(value))) - digits + 1)
    return abs(shown - value) <= 0.5 * scale * (1 + 1e-9)


def check_margins(shown, report):
    assert shown['stable'] == ('yes' if report.stable else 'NO')
    assert abs(float(shown['phase_margin']) - report.phase_margin) <= 0.05 + 1e-9
    for key in ('gain_margin', 'ms', 'mt', 'delay_margin', 'wc', 'w180'):
        assert agrees(shown[key], getattr(report, key), 3), (key, shown[key], report)


def test_the_robustness_panel_shows_the_margins_of_the_analysis_and_follows_kp(page, probe):
    wait = WebDriverWait(page, WAIT)
    wait.until(lambda d: d.find_element(By.ID, 'robustness').get_attribute('data-available')
               == 'true')
    before = expected_margins(20.0)
    assert before.stable and math.isfinite(before.gain_margin)
    wait.until(lambda d: shown_margins(d).get('gain_margin'))
    check_margins(shown_margins(page), before)
    # Bode and Nyquist drawn: both charts hold the curve, the Nyquist canvas the case
    assert int(page.find_element(By.ID, 'bode-mag').get_attribute('data-points')) > 100
    assert page.find_element(By.ID, 'nyquist').get_attribute('data-cases') == '1'
    # Bode: |L| = 1/GM at the phase crossover, as the curves sent to the page say
    curves = page.execute_script('return window.tankRobustness.state.msg')
    w, mag = curves['w'], curves['cases'][0]['mag']
    i = min(range(len(w)), key=lambda k: abs(math.log(w[k] / before.w180)))
    assert abs(mag[i] * before.gain_margin - 1.0) < 0.05

    updates = int(page.find_element(By.ID, 'robustness').get_attribute('data-updates'))
    done = call(probe, SetParameters, '/controller/set_parameters', SetParameters.Request(
        parameters=[Parameter('kp', value=40.0).to_parameter_msg()])).results[0]
    assert done.successful, done.reason
    wait.until(lambda d: int(d.find_element(By.ID, 'robustness').get_attribute('data-updates'))
               > updates and float(shown_margins(d)['gain_margin'])
               != float(f'{before.gain_margin:.3g}'))
    after = expected_margins(40.0)
    assert after.gain_margin < before.gain_margin
    check_margins(shown_margins(page), after)


def test_a_loop_the_analysis_cannot_describe_is_named_in_one_line(procs, ros_env, node_cmd):
    """The mixing tank under the two-loop PI (config/tank_two_loop.yaml): no Bode, one line."""
    params = str(CONFIG / 'tank_two_loop.yaml')
    for module in ('plant_node', 'controller_node'):
        procs.start(module, node_cmd(module, '--params-file', params), env=ros_env)
    dash = procs.start('dashboard', node_cmd('dashboard_node', '-p', 'port:=0'), env=ros_env)
    with chromium_page() as driver:
        driver.get(dashboard_url(dash))
        wait = WebDriverWait(driver, WAIT)
        line = 'controller two_loop_pi: the kind gives no linear description'
        wait.until(lambda d: line in d.find_element(By.ID, 'robustness-reason').text)
        panel = driver.find_element(By.ID, 'robustness')
        assert panel.get_attribute('data-available') == 'false'
        assert not driver.find_element(By.ID, 'robustness-body').is_displayed()
        assert '\n' not in driver.find_element(By.ID, 'robustness-reason').text


def test_the_page_writes_only_from_the_logged_url(procs, ros_env, node_cmd, probe):
    """Opened without the token the page shows the loop read-only (fields and buttons disabled)
    and a set forced from it is refused by the server; from the URL the node logged (with its
    token) an edit reaches the node, also after a visit to the runs page."""
    procs.start('controller', node_cmd('controller_node', '--params-file',
                                       str(CONFIG / 'ipdt_pid.yaml')), env=ros_env)
    dash = procs.start('dashboard', node_cmd('dashboard_node', '-p', 'port:=0'), env=ros_env)
    logged = dashboard_url(dash)
    base, _, query = logged.partition('?')
    assert query.startswith('token=')
    before = controller_param(probe, 'u_max')
    with chromium_page() as driver:
        wait = WebDriverWait(driver, WAIT, ignored_exceptions=(StaleElementReferenceException,))
        driver.get(base)
        wait.until(lambda d: d.find_elements(By.CSS_SELECTOR,
                                             'input[data-node="/controller"][data-param="u_max"]'))
        wait.until(lambda d: 'read-only' in d.find_element(By.ID, 'access').text)
        assert not param_input(driver, 'u_max').is_enabled()
        # the page's own restriction lifted by hand: the server refuses the tokenless set
        driver.execute_script('document.querySelector(\'input[data-param="u_max"]\')'
                              '.disabled = false;')
        type_into(driver, 'u_max', '0.5')
        wait.until(lambda d: 'refused: no token' in reason_text(d, 'u_max'))
        assert controller_param(probe, 'u_max') == before != 0.5

        driver.get(logged)
        wait.until(lambda d: d.find_elements(By.CSS_SELECTOR,
                                             'input[data-node="/controller"][data-param="u_max"]'))
        assert not driver.find_element(By.ID, 'access').is_displayed()
        driver.get(base + 'runs')                 # the token stays with the tab
        driver.get(base)
        wait.until(lambda d: param_input(d, 'u_max').is_enabled())
        type_into(driver, 'u_max', '0.5')
        wait.until(lambda d: 'pending' not in param_input(d, 'u_max').get_attribute('class'))
        assert reason_text(driver, 'u_max') == ''
        assert controller_param(probe, 'u_max') == 0.5
