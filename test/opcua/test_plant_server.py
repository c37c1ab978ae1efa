"""The simulated plant as an OPC UA server (tank_control/opcua/plant_server.py): an asyncua
client in the test browses Objects/Plant, reads the units and ranges, and runs a PI loop on
the project's plant model served as plant_node would (outputs published each tick, the inputs
written by the client taken before each step)."""
from __future__ import annotations

import asyncio
import threading
import time

import numpy as np
import pytest
from asyncua import Client, ua

from support.opcua_servers import free_port
from tank_control.core.scenario import plant_setup
from tank_control.opcua.plant_server import NAMESPACE, PlantServer, mode_reason, unece_id

#: each test starts an asyncua server (4-6 s of start-up on a busy machine)
pytestmark = pytest.mark.slow

TS = 0.05


class PlantLoop:
    """plant_node's use of the component in wall mode, in a thread: step with the inputs
    taken, publish the outputs stamped with the tick's wall time."""

    def __init__(self, server: PlantServer, plant) -> None:
        self.server, self.plant = server, plant
        self.u = {n: 0.0 for n in plant.input_names}
        self.stop = threading.Event()
        self.ticks = 0
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        start = time.monotonic()
        while not self.stop.is_set():
            self.u.update(self.server.take_inputs())
            self.plant.step(np.array([self.u[n] for n in self.plant.input_names]),
                            np.zeros(len(self.plant.disturbance_names)), TS)
            self.ticks += 1
            self.server.publish(time.time_ns(), dict(zip(self.plant.output_names,
                                                         self.plant.outputs())))
            self.stop.wait(max(0.0, start + self.ticks * TS - time.monotonic()))


@pytest.fixture
def served():
    setup = plant_setup({'plant': 'fopdt', 'gain': 2.0, 'time_constant': 0.5, 'dead_time': 0.0,
                         'sample_time': TS, 'range.u': [0.0, 4.0]})
    plant = setup.build_plant()
    server = PlantServer(f'opc.tcp://127.0.0.1:{free_port()}/plant', plant.output_names,
                         plant.input_names, setup.ranges)
    server.start()
    loop = PlantLoop(server, plant)
    yield server, loop
    loop.stop.set()
    loop.thread.join(5)
    server.stop()


def test_an_opc_ua_client_runs_a_pi_loop_on_the_served_plant(served):
    server, loop = served

    async def client_pi() -> tuple[list[float], dict]:
        async with Client(server.endpoint, timeout=10) as client:
            idx = await client.get_namespace_index(NAMESPACE)
            plant = await client.nodes.objects.get_child(f'{idx}:Plant')
            y = await plant.get_child(f'{idx}:y')
            u = await plant.get_child(f'{idx}:u')
            info = {
                'y_writable': await y.read_attribute(ua.AttributeIds.UserAccessLevel),
                'u_writable': await u.read_attribute(ua.AttributeIds.UserAccessLevel),
                'u_range': await (await u.get_child('0:EURange')).read_value(),
                'y_units': await (await y.get_child('0:EngineeringUnits')).read_value(),
            }
            try:
                await y.write_value(1.0)
                info['y_write'] = 'accepted'
            except ua.UaStatusCodeError as exc:
                info['y_write'] = type(exc).__name__
            try:
                await u.write_value(99.0)
                info['u_out_of_range'] = 'accepted'
            except ua.UaStatusCodeError as exc:
                info['u_out_of_range'] = type(exc).__name__
            # PI: kp 0.5, ti 0.5 s (= the lag's time constant), setpoint 1, on each new sample
            kp, ti, integral, seen, ys = 0.5, 0.5, 0.0, None, []
            deadline = time.monotonic() + 60
            while len(ys) < 100 and time.monotonic() < deadline:
                dv = await y.read_data_value()
                if dv.SourceTimestamp == seen:
                    await asyncio.sleep(TS / 5)
                    continue
                seen = dv.SourceTimestamp
                error = 1.0 - dv.Value.Value
                integral += kp * TS / ti * error
                await u.write_value(ua.DataValue(ua.Variant(
                    min(max(kp * error + integral, 0.0), 4.0), ua.VariantType.Double)))
                ys.append(dv.Value.Value)
            return ys, info

    ys, info = asyncio.run(client_pi())
    assert len(ys) == 100
    assert abs(ys[-1] - 1.0) < 0.02 and ys[0] < 0.5        # the loop brought y to its setpoint
    assert server.counters['writes'] >= 100
    assert info['y_write'] == 'BadUserAccessDenied' and info['u_out_of_range'] == 'BadOutOfRange'
    assert info['u_range'].Low == 0.0 and info['u_range'].High == 4.0
    assert info['y_units'].UnitId == unece_id('C62')
    assert not int(info['y_writable'].Value.Value) & 2 and int(info['u_writable'].Value.Value) & 2


def test_lockstep_is_refused_with_its_reason():
    assert mode_reason('wall', 'opc.tcp://0.0.0.0:4840/tank') is None
    assert mode_reason('sim', 'opc.tcp://0.0.0.0:4840/tank') is None
    assert mode_reason('lockstep', '') is None
    reason = mode_reason('lockstep', 'opc.tcp://0.0.0.0:4840/tank')
    assert reason.startswith('opcua.endpoint: ') and 'lockstep' in reason and '/clock' in reason


def test_an_endpoint_that_cannot_be_served_is_one_line_naming_the_parameter():
    port = free_port()
    first = PlantServer(f'opc.tcp://127.0.0.1:{port}/a', ['y'], ['u'])
    first.start()
    try:
        second = PlantServer(f'opc.tcp://127.0.0.1:{port}/b', ['y'], ['u'])
        with pytest.raises(Exception) as err:
            second.start()
        assert str(err.value).startswith(f'opcua.endpoint: opc.tcp://127.0.0.1:{port}/b: ')
        assert '\n' not in str(err.value)
    finally:
        first.stop()
