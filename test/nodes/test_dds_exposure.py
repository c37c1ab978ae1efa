"""What DDS does and does not protect (docs/deployment.md, "What DDS does not protect"), on two
hosts made of network namespaces (test/support/netns.py; needs root, fails without it, marker
``netns``): a controller_node started with ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` on one
host still takes ``ros2 param set`` from the other host when that one names it in
``ROS_STATIC_PEERS`` (LOCALHOST only stops it announcing itself; it listens on every
interface) and the node logs the change (its audit record); with config/fastdds_loopback_only.xml
(UDP on 127.0.0.1 only) the other host cannot find it, while a process on its own host can.
And the Fast DDS of the PyPI wheels has no security plugins: with ``ROS_SECURITY_ENABLE=true``
and an enclave a node stops at start with the middleware's one line."""
from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from support import CONFIG
from support.netns import Host, two_hosts

pytestmark = pytest.mark.netns

PROFILE = CONFIG / 'fastdds_loopback_only.xml'
PARAMS = str(CONFIG / 'ipdt_pid.yaml')
#: the controller's u_max in that file (the value a set changes from)
U_MAX = float(yaml.safe_load(Path(PARAMS).read_text())['controller']['ros__parameters']['u_max'])
WAIT = 60.0


def param_set(host: Host, env: dict[str, str], value: str,
              timeout: float = 20.0) -> subprocess.CompletedProcess:
    """``ros2 param set /controller u_max VALUE`` run on ``host`` (the package's ros2), which
    looks for the node for ``timeout`` seconds."""
    return subprocess.run(host.exec([sys.executable, '-m', 'tank_control.ros2cli.main', 'param',
                                     'set', '/controller', 'u_max', value, '--timeout',
                                     f'{timeout:g}']),
                          env=env, capture_output=True, text=True, timeout=120, check=False)


def start_controller(procs, host: Host, env: dict[str, str]):
    proc = procs.start('controller', host.exec([sys.executable, '-m',
                                                'tank_control.nodes.controller_node',
                                                '--ros-args', '--params-file', PARAMS]), env=env)
    deadline = time.monotonic() + WAIT
    while 'pid controller' not in proc.log_path.read_text(errors='replace'):
        assert proc.returncode is None and time.monotonic() < deadline, proc.tail()
        time.sleep(0.1)           # polling a log file: no event to wait on
    return proc


@pytest.mark.parametrize('profile', [False, True], ids=['localhost', 'loopback-profile'])
def test_a_remote_host_naming_the_plant_host_changes_gains_unless_loopback_only(
        profile, procs, ros_env):
    local = {**ros_env, 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}
    local.pop('ROS_STATIC_PEERS', None)
    if profile:
        local['FASTRTPS_DEFAULT_PROFILES_FILE'] = str(PROFILE)
    with two_hosts('dds_exposure') as hosts:
        remote = {**ros_env, 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
                  'ROS_STATIC_PEERS': hosts.plant.address}
        proc = start_controller(procs, hosts.plant, local)
        # a node the other host can reach is found in under 2 s (the localhost case, the
        # node's start included); one it cannot is looked for 6 s, then "Node not found"
        done = param_set(hosts.station, remote, '0.5', 20.0 if not profile else 6.0)
        if not profile:
            # LOCALHOST alone: the other host reaches the node and changes its parameter
            assert done.returncode == 0, done.stderr
            assert 'Set parameter successful' in done.stdout
            log = proc.log_path.read_text(errors='replace')
            assert f'parameter u_max: {U_MAX!r} -> 0.5 (set_parameters service)' in log
        else:
            assert done.returncode != 0
            assert "Node not found: '/controller'" in done.stderr, done.stderr
            # the node's own host still reaches it (with the same profile)
            own = param_set(hosts.plant, local, '0.25')
            assert own.returncode == 0, own.stderr
            log = proc.log_path.read_text(errors='replace')
            assert f'u_max: {U_MAX!r} -> 0.25' in log and '-> 0.5' not in log


def test_the_wheels_fast_dds_has_no_security_plugins(tmp_path, ros_env):
    enclave = tmp_path / 'keystore' / 'enclaves' / 'tank_control'
    enclave.mkdir(parents=True)
    for name in ('identity_ca.cert.pem', 'cert.pem', 'key.pem', 'permissions_ca.cert.pem',
                 'governance.p7s', 'permissions.p7s'):
        (enclave / name).write_text('placeholder\n')   # rcl checks they exist; DDS reads them
    env = {**ros_env, 'ROS_SECURITY_ENABLE': 'true', 'ROS_SECURITY_STRATEGY': 'Enforce',
           'ROS_SECURITY_KEYSTORE': str(tmp_path / 'keystore'),
           'ROS_SECURITY_ENCLAVE_OVERRIDE': '/tank_control'}
    run = subprocess.run([sys.executable, '-m', 'tank_control.nodes.controller_node',
                          '--ros-args', '--params-file', PARAMS], env=env,
                         capture_output=True, text=True, timeout=120, check=False)
    assert run.returncode == 2
    assert run.stderr.strip().splitlines()[-1] == (
        "controller_node: error creating node: This Fast DDS version doesn't have the "
        'security libraries'), run.stderr
