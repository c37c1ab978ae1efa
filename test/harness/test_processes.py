"""CPU accounting of node processes (``run.cpu_ms_per_tick`` in metrics.json)."""
from __future__ import annotations

import os
import subprocess
import sys

from tank_control.harness.processes import process_cpu_seconds

# Burns 0.3 s of its own CPU time, prints that time and waits until stdin closes.
BURN = ('import sys, time\n'
        'while time.process_time() < 0.3: pass\n'
        'print(time.process_time(), flush=True)\n'
        'sys.stdin.read()\n')


def test_cpu_seconds_of_a_child_is_its_own_process_time():
    child = subprocess.Popen([sys.executable, '-c', BURN], stdin=subprocess.PIPE,
                             stdout=subprocess.PIPE, text=True)
    try:
        own = float(child.stdout.readline())
        seen = process_cpu_seconds(child.pid)
    finally:
        child.communicate('', timeout=30)
    # /proc counts in clock ticks (1/100 s); the interpreter's start-up is in both numbers.
    assert seen is not None and abs(seen - own) <= 0.02


def test_cpu_seconds_of_this_process_and_of_none():
    assert process_cpu_seconds(os.getpid()) > 0
    assert process_cpu_seconds(2 ** 22 + 12345) is None      # above pid_max: no such process
