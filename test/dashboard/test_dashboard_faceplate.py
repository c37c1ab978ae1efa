"""The dashboard's faceplates in a real browser (headless Chromium) at a laptop's size, 1366×768,
on live loops over real DDS (docs/dashboard.md, "Faceplates"): the IPDT PID of
config/ipdt_pid.yaml and the two PI loops of config/tank_two_loop.yaml, each with plant, controller,
reference and dashboard_node, lockstep at 10x real time.

Without scrolling the operator sees each controller's faceplate (SP, PV, OP with their bars, the
mode), the first trend and the auto-tuning controls; a mode change asks for confirmation (old ->
new) and one click undoes it; a refused value shows the node's reason and the field returns to the
running value. Screenshots go to the test's tmp directory (``faceplate-*.png``) for review."""
from __future__ import annotations

from pathlib import Path

import pytest
from rcl_interfaces.srv import GetParameters
from rclpy.parameter import parameter_value_to_python
from selenium.common.exceptions import StaleElementReferenceException
from selenium.webdriver.common.by import By
from selenium.webdriver.common.keys import Keys
from selenium.webdriver.support.ui import WebDriverWait
from support import CONFIG
from support.browser import chromium_page, dashboard_url

WAIT = 60.0                  # s: a loaded 2-core machine; every wait ends at its event
LAPTOP = (1366, 768)
FACEPLATE = '[data-testid="faceplate-/controller"]'


def start_loop(procs, ros_env, node_cmd, tmp_path: Path, scenario: str) -> str:
    """plant, controller and reference of ``config/<scenario>`` at 10x real time and the
    dashboard on a free port; the dashboard's URL."""
    text = (CONFIG / scenario).read_text()
    paced = 'real_time_factor: 1.0 '
    assert paced in text
    params = tmp_path / scenario
    params.write_text(text.replace(paced, 'real_time_factor: 10.0 '))
    for module in ('plant_node', 'controller_node', 'reference_node'):
        procs.start(module, node_cmd(module, '--params-file', str(params)), env=ros_env)
    return dashboard_url(procs.start('dashboard', node_cmd('dashboard_node', '-p', 'port:=0'),
                                     env=ros_env))


@pytest.fixture
def laptop():
    with chromium_page(*LAPTOP) as driver:
        yield driver


def waiter(driver) -> WebDriverWait:
    # the page re-renders a faceplate when the node's values change: find elements anew
    return WebDriverWait(driver, WAIT, ignored_exceptions=(StaleElementReferenceException,))


#: The parts of the page that must fit a laptop screen: (what, selector of the part within the
#: first element of the scope, scope); every SP, PV and OP of the faceplate, one of the others.
PARTS = (('sp', '[data-testid="sp"]', FACEPLATE), ('pv', '[data-testid="pv"]', FACEPLATE),
         ('op', '[data-testid="op"]', FACEPLATE), ('mode', '[data-testid="mode"]', FACEPLATE),
         ('auto-tuning controls', '[data-testid="autotune-/controller"]', 'body'),
         ('the first trend', '#trends .chart', 'body'), ('zoom/pan controls', '#live', 'body'))


def layout(driver) -> dict:
    """The window, its scroll and the rectangle of each of ``PARTS``, read in one script: the
    page draws a faceplate anew when the node's values change, so elements found by one call
    may be gone at the next."""
    return driver.execute_script(
        'const box = (e) => { const r = e.getBoundingClientRect();'
        ' return {left: r.left, top: r.top, right: r.right, bottom: r.bottom}; };'
        'const parts = [];'
        'for (const [what, selector, scope] of arguments[0]) {'
        ' const within = document.querySelector(scope);'
        ' const found = within ? [...within.querySelectorAll(selector)] : [];'
        ' if (what === "sp" || what === "pv" || what === "op") found.forEach('
        '   (e) => parts.push([what, box(e)]));'
        ' else parts.push([what, found.length ? box(found[0]) : null]); }'
        'return {width: innerWidth, height: innerHeight, scrollY: scrollY, parts: parts};',
        [list(part) for part in PARTS])


def assert_in_view(driver) -> None:
    """Every part of ``PARTS`` lies wholly inside the window, with the page not scrolled."""
    page = layout(driver)
    assert page['scrollY'] == 0, page
    for part in ('sp', 'pv', 'op'):
        assert any(what == part for what, _ in page['parts']), (part, page)
    for what, r in page['parts']:
        assert r is not None, (what, 'not on the page')
        assert r['right'] > r['left'] and r['bottom'] > r['top'], (what, r)
        assert 0 <= r['left'] and r['right'] <= page['width'], (what, r, page['width'])
        assert 0 <= r['top'] and r['bottom'] <= page['height'], (what, r, page['height'])


def controller_param(probe, name):
    client = probe.node.create_client(GetParameters, '/controller/get_parameters')
    try:
        assert probe.wait_for(client.service_is_ready, WAIT)
        future = client.call_async(GetParameters.Request(names=[name]))
        assert probe.wait_for(future.done, WAIT)
        return parameter_value_to_python(future.result().values[0])
    finally:
        probe.node.destroy_client(client)


def faceplate_values(driver) -> dict[str, list[str]]:
    return driver.execute_script(
        'const fp = document.querySelector(arguments[0]); const out = {};'
        'for (const k of ["sp", "pv", "op"]) out[k] = [...fp.querySelectorAll('
        '`[data-testid=${k}] .fp-value`)].map((e) => e.textContent);'
        'return out;', FACEPLATE)


def check_layout(driver, loops: int, tmp_path: Path, name: str) -> None:
    wait = waiter(driver)
    wait.until(lambda d: d.find_element(By.ID, 'connection').text == 'live')
    assert driver.execute_script('return [innerWidth, innerHeight]')[0] <= LAPTOP[0]
    wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, FACEPLATE))
    # live numbers in every SP, PV and OP of every loop
    wait.until(lambda d: all(len(v) == loops and '–' not in v
                             for v in faceplate_values(d).values()))
    wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, '.chart .u-over'))
    driver.save_screenshot(str(tmp_path / f'faceplate-{name}.png'))
    assert_in_view(driver)


def test_ipdt_pid_faceplate_trend_and_tuning_fit_a_laptop_screen(procs, ros_env, node_cmd,
                                                                  tmp_path, laptop):
    laptop.get(start_loop(procs, ros_env, node_cmd, tmp_path, 'ipdt_pid.yaml'))
    check_layout(laptop, 1, tmp_path, 'ipdt')
    # (the faceplate is drawn anew when the node's values change: each element is looked up
    # again until it shows the value)
    def shows(selector: str, read, expected) -> bool:
        return waiter(laptop).until(
            lambda d: read(d.find_element(By.CSS_SELECTOR, selector)) == expected)
    assert shows(f'{FACEPLATE} [data-testid="mode"]', lambda e: e.get_attribute('data-mode'),
                 'auto')
    # the tuning rule is a select of the rule names, not a text box
    assert shows('[data-testid="autotune-/controller"] select[data-param="tuning.rule"]',
                 lambda e: e.get_attribute('value'), 'mdp')
    # the OP bar is drawn against the controller's limits, written readably
    assert shows(f'{FACEPLATE} [data-testid="op"] .bar-limits', lambda e: e.text, '-100 … 100')
    # the loop monitor's verdict (controller_node's /diagnostics) as a badge of the faceplate
    def status() -> str:
        return laptop.find_element(By.CSS_SELECTOR, f'{FACEPLATE} [data-testid="status"]').text
    waiter(laptop).until(lambda d: 'loop y: ' in status())
    assert status().split('loop y: ', 1)[1].strip(), status()


def test_tank_two_loop_faceplate_shows_both_loops_with_units(procs, ros_env, node_cmd, tmp_path,
                                                            laptop):
    laptop.get(start_loop(procs, ros_env, node_cmd, tmp_path, 'tank_two_loop.yaml'))
    check_layout(laptop, 2, tmp_path, 'tank')
    # the units come with the plant's parameters, which may reach the dashboard after the
    # faceplate was first drawn (a loaded machine): wait until they are shown
    expected = ['cm', 'cm', 'cm³/s', '°C', '°C', 'cm³/s']

    def units(d) -> list[str]:
        return d.execute_script(
            'return [...document.querySelectorAll(arguments[0] + " .fp-unit")]'
            '.map((e) => e.textContent);', FACEPLATE)
    waiter(laptop).until(lambda d: units(d) == expected, f'faceplate units, expected {expected}')

    def heading(d) -> str:
        return d.find_element(By.CSS_SELECTOR, '.chart[data-chart="y-h"] h3').text
    waiter(laptop).until(lambda d: heading(d) == 'output h [cm]', 'trend heading with its unit')
    def gains(d) -> str:
        return d.find_element(By.CSS_SELECTOR, f'{FACEPLATE} [data-testid="gains"]').text
    waiter(laptop).until(lambda d: all(g in gains(d) for g in ('two_loop.kp_h', 'two_loop.ki_T')),
                         'both loops\' gains on the faceplate')


def test_a_mode_change_is_confirmed_and_undone_and_a_refusal_restores_the_field(
        procs, ros_env, node_cmd, tmp_path, laptop, probe):
    laptop.get(start_loop(procs, ros_env, node_cmd, tmp_path, 'ipdt_pid.yaml'))
    wait = waiter(laptop)
    mode = f'{FACEPLATE} [data-testid="mode"]'
    manual = f'{FACEPLATE} [data-testid="manual-output"]'
    wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, f'{mode} button[data-mode="manual"]'))
    assert not laptop.find_element(By.CSS_SELECTOR, manual).is_enabled()   # auto: not editable

    # cancelled: nothing is sent
    laptop.find_element(By.CSS_SELECTOR, f'{mode} button[data-mode="manual"]').click()
    wait.until(lambda d: d.find_element(By.ID, 'confirm').is_displayed())
    assert laptop.find_element(By.ID, 'confirm-text').text == '/controller: mode auto → manual'
    laptop.find_element(By.ID, 'confirm-cancel').click()
    wait.until(lambda d: not d.find_element(By.ID, 'confirm').is_displayed())

    # confirmed: the controller is in manual, the manual output becomes editable
    laptop.find_element(By.CSS_SELECTOR, f'{mode} button[data-mode="manual"]').click()
    wait.until(lambda d: d.find_element(By.ID, 'confirm').is_displayed())
    laptop.save_screenshot(str(tmp_path / 'faceplate-confirm.png'))
    laptop.find_element(By.ID, 'confirm-apply').click()
    wait.until(lambda d: d.find_element(By.CSS_SELECTOR, mode).get_attribute('data-mode')
               == 'manual')
    assert controller_param(probe, 'mode') == 'manual'
    wait.until(lambda d: d.find_element(By.CSS_SELECTOR, manual).is_enabled())
    wait.until(lambda d: d.find_element(By.ID, 'undo').is_displayed())
    assert laptop.find_element(By.ID, 'undo-text').text == \
        '/controller: mode auto → manual applied'
    laptop.save_screenshot(str(tmp_path / 'faceplate-undo.png'))

    # one click undoes it
    laptop.find_element(By.ID, 'undo-button').click()
    wait.until(lambda d: d.find_element(By.CSS_SELECTOR, mode).get_attribute('data-mode')
               == 'auto')
    assert controller_param(probe, 'mode') == 'auto'
    wait.until(lambda d: not d.find_element(By.CSS_SELECTOR, manual).is_enabled())
    # the page's list of changes: exactly the two mode changes the controller applied (the
    # cancelled one sent nothing)
    wait.until(lambda d: [(r['old'], r['new']) for r in d.execute_script(
        'return window.tankDashboard.audit') if r['name'] == 'mode' and
        r['node'] == '/controller' and r['source'] == 'set_parameters service'] ==
        [('auto', 'manual'), ('manual', 'auto')])

    # a refused gain: the node's reason beside the field, which shows the running value again
    running = controller_param(probe, 'kp')
    kp = laptop.find_element(By.CSS_SELECTOR, f'{FACEPLATE} input[data-param="kp"]')
    kp.click()
    kp.send_keys(Keys.CONTROL, 'a')
    kp.send_keys('-1', Keys.ENTER)
    wait.until(lambda d: d.find_element(By.ID, 'confirm').is_displayed())
    assert laptop.find_element(By.ID, 'confirm-text').text == \
        f'/controller: kp {running} → -1'
    laptop.find_element(By.ID, 'confirm-apply').click()
    reason = f'{FACEPLATE} .reason[data-param="kp"]'
    wait.until(lambda d: d.find_element(By.CSS_SELECTOR, reason).text ==
               '"-1" refused: kp: -1 is below the minimum; allowed [0, 1e+12]')
    wait.until(lambda d: d.find_element(By.CSS_SELECTOR, f'{FACEPLATE} input[data-param="kp"]')
               .get_attribute('value') == str(running))
    assert controller_param(probe, 'kp') == running
    laptop.save_screenshot(str(tmp_path / 'faceplate-refused.png'))


def analyze_row(capsys, *sets: str) -> dict[str, str]:
    """The plant row of `tank-control analyze config/ipdt_pid.yaml --set ...` by column."""
    from tank_control.harness import cli
    argv = ['analyze', str(CONFIG / 'ipdt_pid.yaml')]
    for item in sets:
        argv += ['--set', item]
    capsys.readouterr()
    assert cli.main(argv) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith('|')]
    header = [c.strip() for c in lines[0].strip('|').split('|')]
    plant = next(line for line in lines if line.startswith('| plant'))
    return dict(zip(header, (c.strip() for c in plant.strip('|').split('|'))))


def agrees(shown: float, printed: str) -> bool:
    """``shown`` rounds to ``printed`` (analyze's digits)."""
    digits = len(printed.split('.')[1]) if '.' in printed else 0
    return abs(shown - float(printed)) <= 0.5 * 10 ** -digits + 1e-12


def test_the_tuning_view_predicts_analyzes_margins_then_applies_and_reverts(
        procs, ros_env, node_cmd, tmp_path, laptop, probe, capsys):
    laptop.get(start_loop(procs, ros_env, node_cmd, tmp_path, 'ipdt_pid.yaml'))
    wait = waiter(laptop)
    view = '[data-testid="tuning-/controller"]'
    wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, f'{view} summary'))
    laptop.find_element(By.CSS_SELECTOR, f'{view} summary').click()
    knob = laptop.find_element(By.CSS_SELECTOR, f'{view} select[data-tv="knob"]')
    assert knob.get_attribute('value') == 'tuning.ms_target'
    value = laptop.find_element(By.CSS_SELECTOR, f'{view} input[data-tv="value"]')
    value.click()
    value.send_keys(Keys.CONTROL, 'a')
    value.send_keys('1.6')
    rule = laptop.find_element(By.CSS_SELECTOR, f'{view} select[data-tv="rule"]')
    laptop.execute_script('arguments[0].value = "ms";'
                          'arguments[0].dispatchEvent(new Event("change"));', rule)
    result = 'return (window.tankDashboard.tuning["/controller"] || {}).result || {}'
    wait.until(lambda d: d.execute_script(result).get('available') is True)
    shown = laptop.execute_script(result)
    # nothing applied yet: the controller still runs its file's rule and gains
    assert controller_param(probe, 'tuning.rule') == 'mdp'
    row = analyze_row(capsys, 'controller.tuning.rule=ms', 'controller.tuning.ms_target=1.6')
    margins = shown['margins']
    for key, column in (('gain_margin', 'GM'), ('phase_margin', 'PM [deg]'), ('ms', 'Ms'),
                        ('mt', 'Mt'), ('delay_margin', 'delay margin [s]')):
        assert agrees(margins[key], row[column]), (key, margins[key], row[column])
    assert len(shown['t']) > 10 and shown['overshoot'] >= 0
    laptop.save_screenshot(str(tmp_path / 'faceplate-tuning.png'))

    # Apply: one confirmation for both changes; the controller derives the previewed gains
    laptop.find_element(By.CSS_SELECTOR, f'{view} button[data-tv="apply"]').click()
    wait.until(lambda d: d.find_element(By.ID, 'confirm').is_displayed())
    assert laptop.find_element(By.ID, 'confirm-text').text == \
        '/controller: tuning.ms_target 1.4 → 1.6, tuning.rule mdp → ms'
    laptop.find_element(By.ID, 'confirm-apply').click()
    assert probe.wait_for(lambda: controller_param(probe, 'tuning.rule') == 'ms', WAIT)
    assert controller_param(probe, 'kp') == pytest.approx(shown['gains']['kp'], rel=1e-9)
    # the page has every applied value (each one re-draws the faceplate: a click during those
    # re-draws may land beside the button, as the layout shifts)
    page_values = ('const p = window.tankDashboard.nodes["/controller"].params;'
                   'return ["tuning.rule", "kp", "ti", "td", "b", "c"].map((n) => p[n].value);')
    wait.until(lambda d: d.execute_script(page_values)[0] == 'ms' and all(
        v == pytest.approx(shown['gains'][k], rel=1e-9) for k, v in
        zip(('kp', 'ti', 'td', 'b', 'c'), d.execute_script(page_values)[1:])))
    wait.until(lambda d: d.find_element(By.CSS_SELECTOR,
                                        f'{view} button[data-tv="revert"]').is_enabled())
    # Revert: the rule and its setting from before, and with them the gains
    laptop.find_element(By.CSS_SELECTOR, f'{view} button[data-tv="revert"]').click()
    assert probe.wait_for(lambda: controller_param(probe, 'tuning.rule') == 'mdp', WAIT)
    assert controller_param(probe, 'tuning.ms_target') == 1.4


def test_a_preview_asked_before_the_plant_is_known_is_computed_when_it_appears(
        procs, ros_env, node_cmd, tmp_path, laptop):
    # the dashboard and the controller first: the tuning view is asked before any plant node
    text = (CONFIG / 'ipdt_pid.yaml').read_text().replace('real_time_factor: 1.0 ',
                                                           'real_time_factor: 10.0 ')
    params = tmp_path / 'ipdt_pid.yaml'
    params.write_text(text)
    procs.start('controller_node', node_cmd('controller_node', '--params-file', str(params)),
                env=ros_env)
    laptop.get(dashboard_url(procs.start('dashboard', node_cmd('dashboard_node', '-p', 'port:=0'),
                                         env=ros_env)))
    wait = waiter(laptop)
    view = '[data-testid="tuning-/controller"]'
    wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, f'{view} summary'))
    laptop.find_element(By.CSS_SELECTOR, f'{view} summary').click()
    laptop.find_element(By.CSS_SELECTOR, f'{view} button[data-tv="preview"]').click()
    shown = f'{view} [data-tv="result"]'
    wait.until(lambda d: d.find_element(By.CSS_SELECTOR, shown).text ==
               'no plant node (yet): its parameters are needed (asked again when it is there)')
    # the plant comes: the page asks again by itself and shows the prediction
    procs.start('plant_node', node_cmd('plant_node', '--params-file', str(params)), env=ros_env)
    result = 'return (window.tankDashboard.tuning["/controller"] || {}).result || {}'
    wait.until(lambda d: d.execute_script(result).get('available') is True)
    assert laptop.execute_script(result)['gains']['kp'] > 0
    wait.until(lambda d: 'margins' in d.find_element(By.CSS_SELECTOR, shown).text)
