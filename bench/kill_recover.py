"""What a SIGKILL of the harness leaves, and what ``tank-control recover`` gets back.

Each run: ``tank-control run config/ipdt_pid.yaml --rtf 0`` (lockstep, as fast as possible) in a
ROS_DOMAIN_ID of its own; a probe node watches ``measurement``; ``--at`` wall seconds after the
probe saw tick 0 the harness is killed (SIGKILL). Reported: the latest tick the probe had seen
at the kill, run.mcap's size, whether mcap's standard reader (``make_reader`` + ROS 2 decoder)
reads it, then (unless ``--no-recover``) ``tank-control recover`` and the last tick the
recovered run.mcap holds: the loss in ticks and in wall seconds at the run's pace.

    .venv/bin/python bench/kill_recover.py [--at 5 25] [--runs 3] [--python OTHER_PYTHON]
                                           [--no-recover]

``--python`` runs the harness with another installation (e.g. a wrapper that sets PYTHONPATH
to another checkout) — an older one has no ``recover``: use ``--no-recover``.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def readable(path: Path) -> tuple[bool, int, str]:
    """(read by make_reader, last measurement tick [0.1 s], error)."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    last = -1
    try:
        with open(path, 'rb') as handle:
            reader = make_reader(handle, decoder_factories=[DecoderFactory()])
            for _, channel, _, msg in reader.iter_decoded_messages():
                if channel.topic == '/measurement':
                    last = max(last, round((msg.header.stamp.sec
                                            + msg.header.stamp.nanosec * 1e-9) * 10))
    except Exception as exc:       # noqa: BLE001 - what the reader says is the result
        return False, last, f'{type(exc).__name__}: {str(exc)[:80]}'
    return True, last, ''


def one(at: float, python: str, recover: bool) -> dict:
    import rclpy
    from sensor_msgs.msg import JointState

    from tank_control.harness import domains
    out = Path(tempfile.mkdtemp(prefix='kill_recover_')) / 'run'
    with domains.claimed() as domain:
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain),
                   ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1')
        context = rclpy.Context()
        rclpy.init(context=context, domain_id=domain)
        node = rclpy.create_node('kill_recover_probe', context=context)
        executor = rclpy.executors.SingleThreadedExecutor(context=context)
        executor.add_node(node)
        latest = [-1]

        def seen(msg: JointState) -> None:
            latest[0] = max(latest[0], round((msg.header.stamp.sec
                                              + msg.header.stamp.nanosec * 1e-9) * 10))
        node.create_subscription(JointState, 'measurement', seen, 10)
        harness = subprocess.Popen(
            [python, '-m', 'tank_control.harness.cli', 'run', str(REPO / 'config/ipdt_pid.yaml'),
             '--out', str(out), '--duration', '100000', '--rtf', '0', '--quiet'], env=env,
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
            cwd=out.parent)
        try:
            deadline = time.monotonic() + 120
            while latest[0] < 0 and time.monotonic() < deadline:
                executor.spin_once(timeout_sec=0.1)
            start = time.monotonic()
            while time.monotonic() - start < at:       # the kill instant is the measurement
                executor.spin_once(timeout_sec=0.05)
            at_kill = latest[0]
            harness.send_signal(signal.SIGKILL)
            harness.wait()
        finally:
            harness.kill()
            harness.wait()
            executor.shutdown()
            node.destroy_node()
            rclpy.try_shutdown(context=context)
        size = (out / 'run.mcap').stat().st_size if (out / 'run.mcap').exists() else 0
        ok, last, error = readable(out / 'run.mcap') if size else (False, -1, 'empty file')
        result = {'at': at, 'seen_tick': at_kill, 'bytes': size, 'readable': ok, 'error': error}
        if recover:
            subprocess.run([sys.executable, '-m', 'tank_control.harness.cli', 'recover',
                            str(out)], env=env, check=True, stdout=subprocess.DEVNULL)
            ok, last, error = readable(out / 'run.mcap')
            run = json.loads((out / 'metrics.json').read_text())['run']
            result.update(recovered_readable=ok, recovered_tick=last, rate=run['ticks_per_s'],
                          lost_ticks=at_kill - last,
                          lost_s=(at_kill - last) / run['ticks_per_s'])
    shutil.rmtree(out.parent)
    return result


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--at', type=float, nargs='+', default=[5.0, 25.0])
    parser.add_argument('--runs', type=int, default=3)
    parser.add_argument('--python', default=sys.executable)
    parser.add_argument('--no-recover', action='store_true')
    args = parser.parse_args()
    results: dict[float, list[dict]] = {}
    for run in range(args.runs):
        for at in args.at:
            r = one(at, args.python, not args.no_recover)
            results.setdefault(at, []).append(r)
            print(f'run {run + 1}: {json.dumps(r)}', flush=True)
    if not args.no_recover:
        print('\n| killed after | ticks/s | lost ticks | lost wall s | recovered readable |')
        print('|---|---|---|---|---|')
        for at, rs in results.items():
            def med(key: str, fmt: str) -> str:
                values = [r[key] for r in rs]
                return (f'{statistics.median(values):{fmt}} '
                        f'({min(values):{fmt}}–{max(values):{fmt}})')
            print(f'| {at:g} s | {med("rate", ".0f")} | {med("lost_ticks", ".0f")} | '
                  f'{med("lost_s", ".2f")} | {all(r["recovered_readable"] for r in rs)} |')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
