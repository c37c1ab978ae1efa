"""Test OPC UA servers (asyncua) on loopback: a plant simulated inside the server (the test's own
model, not the project's), run in a thread of the test process.

``LagServer``: a first-order lag ``T y' = K u - y`` discretised exactly with the sample time,
stepped on its own wall-clock grid; ``Objects/Tank/Level`` (Double, read-only; SourceTimestamp
= the step's instant) and ``Objects/Tank/Inflow`` (Double, writable). Every write a client makes
is recorded (``writes``); the server can be stopped and started again on the same port while
the simulation goes on (a PLC whose OPC UA server restarts), and the level's StatusCode set.
"""
from __future__ import annotations

import asyncio
import datetime
import math
import threading
import time
from collections.abc import Callable
from typing import Any

from asyncua import Server, ua
from asyncua.common.callback import CallbackType

from support.ports import free_port

NS_URI = 'urn:tank_control:test'


class LoopThread:
    """An asyncio loop in a daemon thread; ``call(coro)`` runs a coroutine on it."""

    def __init__(self) -> None:
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()

    def call(self, coro: Any, timeout: float = 60.0) -> Any:
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout)

    def close(self) -> None:
        async def cancel_all() -> None:
            tasks = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
        try:
            self.call(cancel_all(), 10)
        finally:
            self.loop.call_soon_threadsafe(self.loop.stop)
            self.thread.join(10)


async def make_server(port: int, setup: Callable[[Server], Any] | None = None,
                      name: str = 'test', user_manager: Any = None) -> Server:
    """An initialised (not yet started) asyncua server on 127.0.0.1:``port``; ``setup``
    (maybe async) configures it before it starts (security, identity tokens)."""
    server = Server(user_manager=user_manager)
    await server.init()
    server.set_endpoint(f'opc.tcp://127.0.0.1:{port}/{name}')
    server.set_server_name(f'tank_control {name}')
    if setup is not None:
        result = setup(server)
        if asyncio.iscoroutine(result):
            await result
    return server


class LagServer:
    """The first-order plant inside an asyncua server (module doc)."""

    def __init__(self, ts: float = 0.1, gain: float = 2.0, tau: float = 1.0, u0: float = 0.0,
                 port: int | None = None, setup: Callable[[Server], Any] | None = None,
                 user_manager: Any = None) -> None:
        self.ts, self.gain, self.tau = ts, gain, tau
        self.port = port or free_port()
        self.endpoint = f'opc.tcp://127.0.0.1:{self.port}/test'
        self._setup = setup
        self._user_manager = user_manager
        self.y = 0.0
        self.u = u0
        self.k = 0
        # (k, stamp_ns, y_k, u integrated over [k, k+1): nan until tick k+1)
        self.trace: list[tuple[int, int, float, float]] = []
        self.writes: list[tuple[float, float]] = []            # (monotonic s, value written)
        self.status = ua.StatusCodes.Good
        self.source_stamps = True          # False: the level is served without SourceTimestamp
        self.level_nodeid = ''
        self.inflow_nodeid = ''
        self.up = False
        self._server: Server | None = None
        self._stopped: Server | None = None
        self._level: Any = None
        self._inflow: Any = None
        self._loop = LoopThread()
        self._ticker: asyncio.Future | None = None
        self._lock = threading.Lock()

    # ---------------------------------------------------------------- control
    def start(self) -> LagServer:
        self._loop.call(self._start())
        if self._ticker is None:
            self._ticker = asyncio.run_coroutine_threadsafe(self._tick_loop(), self._loop.loop)
        return self

    def stop_server(self) -> None:
        """Stop the OPC UA server (the simulation goes on with the input held)."""
        self._loop.call(self._stop())

    def close(self) -> None:
        if self._ticker is not None:
            self._ticker.cancel()
        try:
            self._loop.call(self._stop())
        finally:
            self._loop.close()

    def set_status(self, code: int) -> None:
        """The StatusCode the level is served with from the next step on."""
        self.status = code

    def snapshot(self) -> tuple[list[tuple[int, int, float, float]], list[tuple[float, float]]]:
        with self._lock:
            return list(self.trace), list(self.writes)

    # --------------------------------------------------------------- internals
    async def _start(self) -> None:
        if self._stopped is not None:        # the same server (address space) again
            server, self._stopped = self._stopped, None
            await server.start()
            self._server = server
            self.up = True
            return
        server = await make_server(self.port, self._setup, user_manager=self._user_manager)
        idx = await server.register_namespace(NS_URI)
        tank = await server.nodes.objects.add_object(ua.NodeId('Tank', idx), 'Tank')
        self._level = await tank.add_variable(ua.NodeId('Tank.Level', idx), 'Level',
                                              ua.Variant(self.y, ua.VariantType.Double))
        self._inflow = await tank.add_variable(ua.NodeId('Tank.Inflow', idx), 'Inflow',
                                               ua.Variant(self.u, ua.VariantType.Double))
        await self._inflow.set_writable()
        # a string variable and a read-only double, for the wrong-type / not-writable checks
        await tank.add_variable(ua.NodeId('Tank.Name', idx), 'Name', 'tank 1')
        self.level_nodeid = self._level.nodeid.to_string()
        self.inflow_nodeid = self._inflow.nodeid.to_string()
        server.subscribe_server_callback(CallbackType.PostWrite, self._on_write)
        await server.start()
        self._server = server
        self.up = True

    async def _stop(self) -> None:
        server, self._server = self._server, None
        self.up = False
        if server is not None:
            await server.stop()
            self._stopped = server

    def _on_write(self, event: Any, dispatcher: Any) -> None:
        for item, result in zip(event.request_params.NodesToWrite, event.response_params):
            if item.NodeId == self._inflow.nodeid and result.is_good():
                value = float(item.Value.Value.Value)
                with self._lock:
                    self.writes.append((time.monotonic(), value))
                self.u = value

    async def _tick_loop(self) -> None:
        """Tick k: integrate [k-1, k) with the input written during it (the latest value, as
        plant_node does: the answer to measurement k-1 acts from its arrival's next tick on),
        then publish y_k stamped with the tick's instant."""
        a = math.exp(-self.ts / self.tau)
        start = time.monotonic()
        while True:
            if self.k > 0:
                self.y = a * self.y + (1 - a) * self.gain * self.u
                with self._lock:
                    self.trace[-1] = (*self.trace[-1][:3], self.u)
            stamp = time.time_ns()
            await self._publish(stamp)
            with self._lock:
                self.trace.append((self.k, stamp, self.y, math.nan))
            self.k += 1
            await asyncio.sleep(max(0.0, start + self.k * self.ts - time.monotonic()))

    async def _publish(self, stamp: int) -> None:
        if self._server is None:
            return
        when = datetime.datetime.fromtimestamp(stamp / 1e9, datetime.timezone.utc)
        dv = ua.DataValue(Value=ua.Variant(self.y, ua.VariantType.Double),
                          StatusCode=ua.StatusCode(self.status),
                          SourceTimestamp=when if self.source_stamps else None,
                          ServerTimestamp=when)
        await self._server.write_attribute_value(self._level.nodeid, dv)


def wait(condition, timeout: float = 30.0) -> bool:
    """``condition()`` within ``timeout`` s (polled; the bridge runs in its own thread)."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.02)
    return True
