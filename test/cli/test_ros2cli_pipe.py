"""`ros2 … | head`: when the reader of its output goes away the ros2 verbs stop quietly, with no
BrokenPipeError traceback (tank_control/ros2cli/main.py), as cat does."""
from __future__ import annotations

import subprocess
import sys

LOOP = ('import sys\n'
        'from tank_control.ros2cli.main import _guarded\n'
        'sys.exit(_guarded(lambda: [print("x" * 80, flush=True) for _ in range(10 ** 6)]))\n')


def test_a_closed_pipe_ends_a_verb_quietly():
    proc = subprocess.Popen([sys.executable, '-c', LOOP], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    assert proc.stdout.readline().strip() == b'x' * 80       # like `| head -1`
    proc.stdout.close()
    stderr = proc.stderr.read().decode()
    assert proc.wait(timeout=60) == 0
    assert 'Traceback' not in stderr and 'BrokenPipeError' not in stderr, stderr
