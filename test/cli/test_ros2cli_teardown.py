"""A `ros2` command whose work is done ends even when the middleware's teardown does not
(tank_control/ros2cli/common.py, ``TEARDOWN_LIMIT``): seen once in a suite run, `ros2 topic
echo --once` printed its message and then never exited. Here rclpy's shutdown is made to
hang for good; the command must still exit, with its own status and its whole output."""
from __future__ import annotations

import subprocess
import sys

import pytest

SCRIPT = '''
import sys, threading
import rclpy
from tank_control.ros2cli import common, main

common.TEARDOWN_LIMIT = 0.5
rclpy.try_shutdown = lambda *args, **kwargs: threading.Event().wait()   # never returns
sys.exit(main.main(sys.argv[1:]))
'''


@pytest.mark.parametrize('argv, status, error', [
    (('topic', 'list', '--no-daemon', '--spin-time', '0'), 0, None),
    (('topic', 'type', '/nowhere', '--timeout', '0.2'), 1, "'/nowhere'"),
])
def test_a_hung_teardown_ends_with_the_commands_status(ros_env, argv, status, error):
    done = subprocess.run([sys.executable, '-c', SCRIPT, *argv], env=ros_env,
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == status, done.stderr
    lines = done.stderr.splitlines()
    assert lines[-1] == 'ros2: the middleware did not shut down within 0.5 s; exiting without it'
    if error:
        assert len(lines) == 2 and error in lines[0], lines     # the command's own reason
    else:
        assert len(lines) == 1, lines
