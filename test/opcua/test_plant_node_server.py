"""plant_node with ``opcua.endpoint`` (issue 35 §2): the simulated plant served over OPC UA
beside its ROS topics. An asyncua client in the test closes the loop on plant_node running as
a process (wall mode): it reads y from Objects/Plant/y, writes u, and the plant integrates the
written input; lockstep is refused at start with the reason."""
from __future__ import annotations

import asyncio
import subprocess
import sys
import time

import pytest
import yaml
from asyncua import Client

from support.opcua_servers import free_port
from tank_control.opcua.plant_server import NAMESPACE

pytestmark = pytest.mark.slow          # an asyncua server starts (seconds on a busy machine)

TS = 0.05


def params(tmp_path, endpoint: str, clock_mode: str = 'wall') -> str:
    path = tmp_path / 'plant.yaml'
    path.write_text(yaml.safe_dump({'plant': {'ros__parameters': {
        'plant': 'ipdt', 'gain': 1.0, 'dead_time': 0.0, 'sample_time': TS,
        'clock_mode': clock_mode, 'opcua.endpoint': endpoint, 'range.u': [-2.0, 2.0]}}}))
    return str(path)


async def _serve_loop(endpoint: str, deadline: float) -> tuple[float, float, float]:
    """Connect (the server may still be starting), read y, write u = 1 and wait until y has
    risen by 0.2 (an integrator of gain 1: 0.2 s of plant time); (y0, y1, seconds)."""
    while True:
        try:
            client = Client(endpoint, timeout=5)
            await client.connect()
            break
        except (OSError, asyncio.TimeoutError, ConnectionError):
            if time.monotonic() > deadline:
                raise
            await asyncio.sleep(0.2)
    try:
        idx = await client.get_namespace_index(NAMESPACE)
        plant = await client.nodes.objects.get_child(f'{idx}:Plant')
        y = await plant.get_child(f'{idx}:y')
        u = await plant.get_child(f'{idx}:u')
        y0 = float(await y.read_value())
        await u.write_value(1.0)
        start = time.monotonic()
        y1 = y0
        while y1 < y0 + 0.2 and time.monotonic() < deadline:
            await asyncio.sleep(TS)
            y1 = float(await y.read_value())
        return y0, y1, time.monotonic() - start
    finally:
        await client.disconnect()


def test_an_opc_ua_client_drives_plant_node(procs, ros_env, tmp_path):
    endpoint = f'opc.tcp://127.0.0.1:{free_port()}/tank'
    proc = procs.start('plant', [sys.executable, '-m', 'tank_control.nodes.plant_node',
                                 '--ros-args', '--params-file', params(tmp_path, endpoint)],
                       env=ros_env)
    y0, y1, _ = asyncio.run(_serve_loop(endpoint, time.monotonic() + 60.0))
    assert y1 >= y0 + 0.2, (y0, y1, proc.tail())          # the written input was integrated


def test_lockstep_with_an_opc_ua_endpoint_is_refused_with_the_reason(ros_env, tmp_path):
    done = subprocess.run([sys.executable, '-m', 'tank_control.nodes.plant_node', '--ros-args',
                           '--params-file', params(tmp_path, 'opc.tcp://127.0.0.1:4840/x',
                                                   'lockstep')],
                          env=ros_env, capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert 'opcua.endpoint' in done.stderr and 'lockstep' in done.stderr
