"""OPC UA bridge latency at 100 Hz on loopback against a bare asyncua client, in one run.

One asyncua server (a thread of this process) updates ``Meas`` about every ``--period`` with a
new value (a counter) and SourceTimestamp = the update's time, and records when each value comes
back written to ``EchoBare`` or ``EchoBridge`` (PostWrite callback). Each update comes at a
random instant within the first fifth of its period (the subscriptions' publishing interval):
the server's publishing loop of a subscription keeps its phase for the subscription's life, so
with updates on a fixed grid a client would wait a fixed 0..2 ms for every notification, drawn
once per subscription (once per bench run for a bridge that stays up); with the updates spread
over that interval both clients wait 1 ms on average, every run. Alternating phases of
``--duration`` s (after ``WARM_UP_S``), ``--runs`` times each, one client at a time with the
server (the other is not running):

* **bare** — an asyncua client (its own process, as the bridge) subscribed to ``Meas`` (publishing
  and sampling interval ``period / 5``, queue 4, as the bridge's defaults) writes the newest
  value it was notified of back to ``EchoBare`` (one write at a time; values notified meanwhile
  are skipped but the newest, as the bridge's latest-wins slot does).
* **bridge** — opcua_bridge_node (a process, ``sample_time`` = period) publishes ``Meas`` on
  ``measurement``; an echo node (its own process, as a controller is: rclpy's EventsExecutor,
  signals as CDR bytes, as controller_node) answers each with ``manipulated`` (same value, same
  stamp), which the bridge writes to ``EchoBridge``. Bridge and echo start for each phase.

Reported per phase, p50/p99 [ms]: ``round trip`` — server receipt of the echoed value −
its SourceTimestamp (value change → measurement → write, everything); for the bridge also
``to ROS`` — the echo node's receipt − SourceTimestamp (value change → ``measurement``
delivered) and ``from ROS`` — server receipt − the echo's publish time (``manipulated`` → server
write). The figure: bridge round trip / bare round trip (goal <= 1.5 x). Also the CPU time of
the client's process (bare client; opcua_bridge_node, without the echo) per period [ms]: what
the client costs per value, which a busy machine inflates much less than the latencies.

    .venv/bin/python bench/bench_opcua.py [--runs 3] [--duration 15] [--period 0.01]
"""
from __future__ import annotations

import argparse
import asyncio
import json
import logging
import os
import select
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
#: the first seconds of each phase are not measured (the bare client connects and subscribes)
WARM_UP_S = 2.0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return int(s.getsockname()[1])


class EchoServer:
    """The asyncua server: Meas updated every period, echoes recorded with their receipt."""

    def __init__(self, period: float) -> None:
        self.period = period
        self.port = free_port()
        self.endpoint = f'opc.tcp://127.0.0.1:{self.port}/bench'
        self.sent: dict[float, int] = {}            # value -> SourceTimestamp [ns]
        self.echoed: dict[str, dict[float, int]] = {'EchoBare': {}, 'EchoBridge': {}}
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()
        asyncio.run_coroutine_threadsafe(self._start(), self.loop).result(120)

    async def _start(self) -> None:
        from asyncua import Server, ua
        from asyncua.common.callback import CallbackType
        server = Server()
        await server.init()
        server.set_endpoint(self.endpoint)
        idx = await server.register_namespace('urn:tank_control:bench')
        self.ids = {}
        for name in ('Meas', 'EchoBare', 'EchoBridge'):
            var = await server.nodes.objects.add_variable(
                ua.NodeId.from_string(f'ns={idx};s={name}'), ua.QualifiedName(name, idx),
                ua.Variant(0.0, ua.VariantType.Double))
            if name != 'Meas':
                await var.set_writable()
            self.ids[name] = var.nodeid
        server.subscribe_server_callback(CallbackType.PostWrite, self._on_write)
        await server.start()
        self.server = server
        self.task = self.loop.create_task(self._tick())

    def _on_write(self, event, dispatcher) -> None:
        now = time.time_ns()
        for item in event.request_params.NodesToWrite:
            for name in ('EchoBare', 'EchoBridge'):
                if item.NodeId == self.ids[name]:
                    self.echoed[name].setdefault(float(item.Value.Value.Value), now)

    async def _tick(self) -> None:
        from asyncua import ua
        rng = np.random.default_rng(1)
        start, k = time.monotonic(), 0
        while True:
            k += 1
            await asyncio.sleep(max(0.0, start + (k + rng.uniform(0, 0.2)) * self.period
                                    - time.monotonic()))
            stamp = time.time_ns()
            self.sent[float(k)] = stamp
            when = ua.DateTime.fromtimestamp(stamp / 1e9, __import__('datetime').timezone.utc)
            await self.server.write_attribute_value(self.ids['Meas'], ua.DataValue(
                Value=ua.Variant(float(k), ua.VariantType.Double), SourceTimestamp=when,
                ServerTimestamp=when))

    def node_id(self, name: str) -> str:
        return self.ids[name].to_string()

    def round_trips(self, name: str, since_ns: int) -> np.ndarray:
        return np.array([(t - self.sent[v]) / 1e6 for v, t in dict(self.echoed[name]).items()
                         if v in self.sent and self.sent[v] >= since_ns])


def cpu_s(pid: int) -> float:
    """CPU time [s] (user + system) process ``pid`` has used so far."""
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def bare_phase(server: EchoServer, duration: float) -> tuple[int, float]:
    """The bare client (:func:`bare_client`) in its own process, as the bridge is in its own
    (neither shares this process's interpreter lock with the server); returns the time [ns]
    from which it is measured: ``WARM_UP_S`` after it has subscribed (it echoes for
    ``WARM_UP_S + duration`` s from then), and its CPU time per period [ms] over 90 % of
    ``duration``."""
    child = subprocess.Popen([sys.executable, __file__, '--bare-client', server.endpoint,
                              server.node_id('Meas'), server.node_id('EchoBare'),
                              str(server.period), str(duration + WARM_UP_S)],
                             env=dict(os.environ, PYTHONPATH=str(ROOT)), stdout=subprocess.PIPE,
                             text=True)
    assert child.stdout is not None
    assert child.stdout.readline().strip() == 'ready'
    since = time.time_ns() + int(WARM_UP_S * 1e9)
    time.sleep(WARM_UP_S)
    cpu = cpu_s(child.pid)
    time.sleep(0.9 * duration)
    cpu = (cpu_s(child.pid) - cpu) / (0.9 * duration / server.period) * 1e3
    child.wait()
    return since, cpu


def bare_client(endpoint: str, meas: str, echo_id: str, period: float, duration: float) -> None:
    """An asyncua client echoing the newest notified value of ``meas`` to ``echo_id``."""
    from asyncua import Client, ua
    logging.getLogger('asyncua').setLevel(logging.CRITICAL)

    async def run() -> None:
        async with Client(endpoint) as client:
            echo = client.get_node(echo_id)
            queue: asyncio.Queue = asyncio.Queue()

            class Handler:
                def datachange_notification(self, node, val, data) -> None:
                    queue.put_nowait(val)
            interval = period / 5 * 1000
            sub = await client.create_subscription(interval, Handler())
            await sub.subscribe_data_change(client.get_node(meas), sampling_interval=interval,
                                            queuesize=4)
            print('ready', flush=True)
            end = time.monotonic() + duration
            while time.monotonic() < end:
                try:
                    value = await asyncio.wait_for(queue.get(), 0.5)
                except asyncio.TimeoutError:
                    continue
                while not queue.empty():          # the newest value (as the bridge does)
                    value = queue.get_nowait()
                await echo.write_value(ua.DataValue(ua.Variant(value, ua.VariantType.Double)))
    asyncio.run(run())


def echo_node() -> None:
    """A ROS node (this process): ``manipulated`` {u: y} stamped like each ``measurement`` {y},
    spun as every node of the project is (EventsExecutor, CDR bytes in and out). Prints
    ``ready`` at its first measurement; at a line on stdin, its receipt and publish times
    (JSON) and ends."""
    import rclpy
    from rclpy.experimental import EventsExecutor
    from sensor_msgs.msg import JointState

    from tank_control.nodes.cdr import JointStateCdr
    from tank_control.nodes.messages import SIGNAL_QOS, parse_signal
    rclpy.init()
    node = rclpy.create_node('bench_opcua_echo')
    record: list[tuple[int, float, int, int]] = []   # stamp, value, received, published
    pub = node.create_publisher(JointState, 'manipulated', SIGNAL_QOS)
    cdr = JointStateCdr(['u'])

    def on_measurement(data: bytes) -> None:
        received = time.time_ns()
        stamp, _, _, values = parse_signal(data)
        pub.publish(cdr.encode_ns(stamp, values[:1]))
        record.append((stamp, values[0], received, time.time_ns()))
        if len(record) == 1:
            print('ready', flush=True)
    node.create_subscription(JointState, 'measurement', on_measurement, SIGNAL_QOS, raw=True)
    executor = EventsExecutor()
    executor.add_node(node)
    stop = threading.Event()
    threading.Thread(target=lambda: (sys.stdin.readline(), stop.set()), daemon=True).start()
    while not stop.is_set():
        executor.spin_once(timeout_sec=0.05)
    print(json.dumps(record), flush=True)
    executor.remove_node(node)
    node.destroy_node()
    executor.shutdown()
    rclpy.try_shutdown()


def bridge_phase(server: EchoServer, duration: float, params: Path
                 ) -> tuple[int, list, float]:
    """opcua_bridge_node and the echo node (:func:`echo_node`), each in its own process, for
    ``WARM_UP_S + duration`` s once the echo has its first measurement; returns the time [ns]
    from which it is measured, the echo's records and the bridge's CPU time per period [ms]."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    echo = subprocess.Popen([sys.executable, __file__, '--echo'], env=env, text=True,
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    bridge = subprocess.Popen([sys.executable, '-m', 'tank_control.nodes.opcua_bridge_node',
                               '--ros-args', '--params-file', str(params)], env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        assert echo.stdout is not None and echo.stdin is not None
        ready = select.select([echo.stdout], [], [], 60)[0]
        assert ready and echo.stdout.readline().strip() == 'ready', \
            f'the echo node got no measurement within 60 s (bridge exit status {bridge.poll()})'
        since = time.time_ns() + int(WARM_UP_S * 1e9)
        time.sleep(WARM_UP_S)
        cpu = cpu_s(bridge.pid)
        time.sleep(duration)
        cpu = (cpu_s(bridge.pid) - cpu) / (duration / server.period) * 1e3
        echo.stdin.write('stop\n')
        echo.stdin.flush()
        records = json.loads(echo.stdout.readline())
    finally:
        for child in (bridge, echo):
            child.terminate()
            try:
                child.wait(10)
            except subprocess.TimeoutExpired:
                child.kill()
                child.wait()
    return since, records, cpu


def percentiles(values) -> str:
    values = np.asarray(values, dtype=float)
    if not values.size:
        return 'n/a'
    return f'{np.percentile(values, 50):.2f} / {np.percentile(values, 99):.2f}'


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--runs', type=int, default=3)
    parser.add_argument('--duration', type=float, default=15.0)
    parser.add_argument('--period', type=float, default=0.01)
    parser.add_argument('--bare-client', nargs=5, help=argparse.SUPPRESS)
    parser.add_argument('--echo', action='store_true', help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.echo:
        echo_node()
        return 0
    if args.bare_client:
        endpoint, meas, echo_id, period, duration = args.bare_client
        bare_client(endpoint, meas, echo_id, float(period), float(duration))
        return 0
    logging.getLogger('asyncua').setLevel(logging.CRITICAL)
    from tank_control.harness import domains
    domain, lock = domains.claim()
    os.environ['ROS_DOMAIN_ID'] = str(domain)
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    print(f'load average {os.getloadavg()[0]:.1f}; ROS_DOMAIN_ID {domain}', flush=True)
    server = EchoServer(args.period)
    params = {'opcua_bridge': {'ros__parameters': {
        'endpoint': server.endpoint, 'sample_time': args.period,
        'measurement.channels': ['y'], 'measurement.y.node_id': server.node_id('Meas'),
        'manipulated.channels': ['u'], 'manipulated.u.node_id': server.node_id('EchoBridge'),
        'range.u': [0.0, 1e9]}}}
    path = Path(tempfile.mkdtemp()) / 'bridge.yaml'
    path.write_text(json.dumps(params))
    rows: dict[str, list[tuple[float, float]]] = {'bare': [], 'bridge': [], 'to ROS': [],
                                                  'from ROS': [], 'bare CPU': [],
                                                  'bridge CPU': []}
    try:
        for run in range(args.runs):
            since, cpu = bare_phase(server, args.duration)
            rows['bare CPU'].append((cpu, cpu))
            rt = server.round_trips('EchoBare', since)
            rows['bare'].append((np.percentile(rt, 50), np.percentile(rt, 99)))
            print(f'run {run}: bare round trip p50/p99 {percentiles(rt)} ms ({rt.size}), '
                  f'CPU {cpu:.2f} ms per period; load {os.getloadavg()[0]:.1f}', flush=True)
            since, records, cpu = bridge_phase(server, args.duration, path)
            rows['bridge CPU'].append((cpu, cpu))
            rt = server.round_trips('EchoBridge', since)
            echoed = dict(server.echoed['EchoBridge'])
            to_ros = np.array([(received - stamp) / 1e6 for stamp, _, received, _ in records
                               if stamp >= since])
            from_ros = np.array([(echoed[value] - published) / 1e6
                                 for stamp, value, _, published in records
                                 if stamp >= since and value in echoed])
            rows['bridge'].append((np.percentile(rt, 50), np.percentile(rt, 99)))
            rows['to ROS'].append((np.percentile(to_ros, 50), np.percentile(to_ros, 99)))
            rows['from ROS'].append((np.percentile(from_ros, 50), np.percentile(from_ros, 99)))
            print(f'run {run}: bridge round trip p50/p99 {percentiles(rt)} ms ({rt.size}), '
                  f'to ROS {percentiles(to_ros)}, from ROS {percentiles(from_ros)}, '
                  f'CPU {cpu:.2f} ms per period; load {os.getloadavg()[0]:.1f}', flush=True)
    finally:
        lock.close()
    print(f'\nload average after {os.getloadavg()[0]:.1f}')
    print('| path | p50 [ms] | p99 [ms] |\n|---|---|---|')
    for name, values in rows.items():
        if name.endswith('CPU'):
            continue
        p50 = [v[0] for v in values]
        p99 = [v[1] for v in values]
        print(f'| {name} | {np.median(p50):.2f} ({min(p50):.2f}–{max(p50):.2f}) | '
              f'{np.median(p99):.2f} ({min(p99):.2f}–{max(p99):.2f}) |')
    bare = np.median([v[0] for v in rows['bare']])
    bridged = np.median([v[0] for v in rows['bridge']])
    bare99 = np.median([v[1] for v in rows['bare']])
    bridged99 = np.median([v[1] for v in rows['bridge']])
    for name in ('bare', 'bridge'):
        cpu = [v[0] for v in rows[name + ' CPU']]
        print(f'{name} client process CPU per period: {np.median(cpu):.2f} ms '
              f'({min(cpu):.2f}–{max(cpu):.2f})')
    print(f'\nratio bridge / bare round trip: p50 {bridged / bare:.2f}x, '
          f'p99 {bridged99 / bare99:.2f}x')
    return 0


if __name__ == '__main__':
    sys.exit(main())
