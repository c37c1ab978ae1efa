"""The dashboard during a relay auto-tuning test, as a picture for the docs.

Runs ``tank-control run config/scenarios/fopdt_autotune_scheduled.yaml --dashboard PORT`` over
ROS 2 (lockstep at ``--rtf`` times real time; the file starts the relay test at t = 60 s), opens the page in
headless Chromium (Debian's, as the tests do) and saves a screenshot once the auto-tuner has
reached ``--state`` and the trends show ``--after`` seconds past it.

    .venv/bin/python scripts/dashboard_screenshot.py [--out docs/images/dashboard_relay.png]
                                                     [--state measuring] [--after 15] [--rtf 4]
"""
from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / 'test'))          # support.browser: the tests' headless Chromium


def free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--out', default=str(REPO / 'docs/images/dashboard_relay.png'))
    parser.add_argument('--state', default='measuring')
    parser.add_argument('--after', type=float, default=15.0, help='s of plant time after it')
    parser.add_argument('--rtf', type=float, default=4.0)
    parser.add_argument('--domain', type=int, default=93)
    args = parser.parse_args()
    from selenium.webdriver.support.ui import WebDriverWait
    from support.browser import headless_chromium

    port = free_port()
    env = dict(os.environ, ROS_DOMAIN_ID=str(args.domain),
               ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1')
    with tempfile.TemporaryDirectory() as tmp:
        run = subprocess.Popen([sys.executable, '-m', 'tank_control.harness.cli', 'run',
                                str(REPO / 'config/scenarios/fopdt_autotune_scheduled.yaml'), '--out', tmp + '/run',
                                '--rtf', str(args.rtf), '--quiet', '--dashboard', str(port)],
                               env=env, cwd=tmp)
        try:
            with headless_chromium(1400, 1500) as page:
                deadline = time.monotonic() + 120
                while True:                  # the dashboard starts with the run's nodes
                    try:
                        page.get(f'http://127.0.0.1:{port}/')
                        break
                    except Exception:        # noqa: BLE001 - not listening yet
                        if time.monotonic() > deadline or run.poll() is not None:
                            raise
                        time.sleep(0.5)      # polling a port that is not open yet
                marks = ('return window.tankDashboard ? window.tankDashboard.marks'
                         '.filter((m) => m.machine === "autotune") : [];')
                latest = ('const m = window.tankDashboard.topics.measurement;'
                          'return m && m.t.length ? m.t[m.t.length - 1] : -1;')

                def ready(d) -> bool:
                    entered = [m['t'] for m in d.execute_script(marks)
                               if m['label'] == args.state]
                    return bool(entered) and d.execute_script(latest) >= entered[0] + args.after
                WebDriverWait(page, 600).until(ready)
                page.execute_script("document.getElementById('window').value = 120;"
                                    "document.getElementById('window')"
                                    ".dispatchEvent(new Event('change'));")
                WebDriverWait(page, 10).until(lambda d: d.execute_script(
                    'return window.tankDashboard.windowS') == 120)
                time.sleep(0.5)              # one more redraw with the wider window
                Path(args.out).parent.mkdir(parents=True, exist_ok=True)
                page.save_screenshot(args.out)
                print(f'wrote {args.out}')
        finally:
            run.terminate()
            run.wait(timeout=60)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
