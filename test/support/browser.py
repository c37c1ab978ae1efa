"""A headless Chromium driven by Selenium (Debian's chromium and chromium-driver, installed by
the Makefile's setup), and the dashboard_node a test starts.

chromedriver runs in a session of its own (chromium is its child, in the same process group),
dies with the test process, and the whole group is killed when the browser is closed, so no
chromedriver or chromium is left behind. The tests share one browser per test process
(``chromium_page``: starting one costs 1-2 s of both cores), each test on a blank page with
the storage of the page it left cleared; test/dashboard/conftest.py closes it at the end."""
from __future__ import annotations

import os
import re
import signal
import time
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path

from support.procfs import group_members

from tank_control.harness.processes import ManagedProcess, _die_with_parent

CHROMIUM = Path('/usr/bin/chromium')
CHROMEDRIVER = Path('/usr/bin/chromedriver')
URL_LINE = re.compile(r'dashboard at (http://\S+)')


@contextmanager
def headless_chromium(width: int = 1400, height: int = 1000) -> Iterator[object]:
    """A Selenium WebDriver on a headless Chromium; everything is stopped on exit."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    missing = [str(p) for p in (CHROMIUM, CHROMEDRIVER) if not p.exists()]
    assert not missing, (f'{", ".join(missing)} missing: `make setup` as root installs '
                         'chromium and chromium-driver')
    options = webdriver.ChromeOptions()
    options.binary_location = str(CHROMIUM)
    for arg in ('--headless=new', '--no-sandbox', '--disable-dev-shm-usage', '--disable-gpu',
                '--disable-extensions', '--no-first-run', '--disable-crash-reporter',
                '--disable-breakpad', f'--window-size={width},{height}'):
        options.add_argument(arg)
    service = Service(str(CHROMEDRIVER),
                      popen_kw={'start_new_session': True, 'preexec_fn': _die_with_parent()})
    driver = webdriver.Chrome(service=service, options=options)
    pid = service.process.pid
    try:
        yield driver
    finally:
        try:
            driver.quit()
        finally:
            if group_members(pid):                   # anything of the group still there
                os.killpg(pid, signal.SIGKILL)
            deadline = time.monotonic() + 30.0
            while group_members(pid) and time.monotonic() < deadline:
                time.sleep(0.05)                     # SIGKILL delivered; the kernel ends them


_SHARED: list = []          # [driver, the ExitStack that closes it] of this process


@contextmanager
def chromium_page(width: int = 1400, height: int = 1000) -> Iterator[object]:
    """This process's shared headless Chromium (started on first use), its window
    ``width`` x ``height``, on a blank page; on exit an open dialog is dismissed, the page's
    localStorage and the cookies cleared and its tab replaced by a new blank one (a browser
    that cannot be reset is closed: the next test starts a new one)."""
    if not _SHARED:
        stack = ExitStack()
        _SHARED[:] = [stack.enter_context(headless_chromium(width, height)), stack]
    driver = _SHARED[0]
    driver.set_window_size(width, height)
    driver.get('about:blank')
    try:
        yield driver
    finally:
        try:
            _reset(driver)
        except Exception:                            # noqa: BLE001 - a broken browser: a new one
            close_shared_chromium()


def _reset(driver) -> None:
    """A new blank tab (its own sessionStorage) for the next test, the others closed, and
    no cookies or localStorage of the page left."""
    from selenium.common.exceptions import NoAlertPresentException
    try:
        driver.switch_to.alert.dismiss()
    except NoAlertPresentException:
        pass
    driver.execute_script('try { localStorage.clear(); } catch (e) {}')
    driver.delete_all_cookies()
    old = driver.window_handles
    driver.switch_to.new_window('tab')
    fresh = driver.current_window_handle
    for handle in old:
        driver.switch_to.window(handle)
        driver.close()
    driver.switch_to.window(fresh)


def close_shared_chromium() -> list[int]:
    """Stop the shared browser, if one runs; the processes of its group still there after
    (none: ``headless_chromium`` kills the group)."""
    if not _SHARED:
        return []
    driver, stack = _SHARED
    _SHARED.clear()
    pid = driver.service.process.pid
    stack.close()
    return group_members(pid)


def base_url(url: str) -> str:
    """``http://host:port/`` of a logged dashboard URL (without its ``?token=``)."""
    return url.partition('?')[0]


def dashboard_url(proc: ManagedProcess, timeout: float = 60.0) -> str:
    """The URL dashboard_node logs once its web server listens (port 0: any free port), with
    this start's ``?token=`` (the page may write) unless the dashboard is read-only."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        found = URL_LINE.search(proc.log_path.read_text(errors='replace'))
        if found:
            return found.group(1)
        assert proc.returncode is None, f'dashboard_node exited:\n{proc.tail()}'
        time.sleep(0.1)            # polling a log file: no event to wait on
    raise AssertionError(f'dashboard_node logged no URL in {timeout:g} s:\n{proc.tail()}')
