"""A lockstep run with an external controller (``harness.external_nodes``, docs/harness.md) against
the same run with the harness's own controller_node: run wall time and ticks per second.

The external controller is the bare-rclpy PI of test/harness/test_external_nodes.py (``EXTERNAL``),
started here before each run; the built-in run uses controller_node with ``pid`` (kp, ti of the
same PI). Each run in its own claimed ROS_DOMAIN_ID, alternating, ``--runs`` of each; prints the
median.

    PYTHONPATH=$PWD .venv/bin/python bench/bench_external.py --runs 3 --duration 100
"""
from __future__ import annotations

import argparse
import importlib.util
import os
import statistics
import sys
import tempfile
from pathlib import Path

from tank_control.harness import domains
from tank_control.harness.processes import ProcessGroup
from tank_control.harness.runner import run_scenario
from tank_control.harness.scenario_file import load_scenario

ROOT = Path(__file__).resolve().parents[1]


def _test_module():
    path = ROOT / 'test' / 'harness' / 'test_external_nodes.py'
    spec = importlib.util.spec_from_file_location('test_external_nodes', path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def one_run(external: bool, duration: float, work: Path, env: dict[str, str]) -> dict:
    t = _test_module()
    path = work / 'scenario.yaml'
    text = t.SCENARIO
    if not external:
        text = text.replace("external_nodes: ['controller'], ", '') + (
            'controller:\n  ros__parameters: {controller: pid, sample_time: 0.1, '
            f"kp: {t.KP}, ti: {t.TI}, output_names: ['y'], input_names: ['u']}}\n")
    path.write_text(text)
    scenario = load_scenario(path, [f'harness.duration={duration}'])
    with ProcessGroup(work / 'logs') as group:
        if external:
            script = work / 'my_controller.py'
            script.write_text(t.EXTERNAL)
            group.start('my_controller', [sys.executable, str(script)], env=env)
        result = run_scenario(scenario, work / 'out', env=env)
    run = result.metrics['run']
    return {'wall_time': run['wall_time'], 'ticks_per_s': run['ticks_per_s'],
            'ticks': run['ticks']}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--runs', type=int, default=3)
    parser.add_argument('--duration', type=float, default=100.0)
    args = parser.parse_args()
    domain, lock = domains.claim()
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), PYTHONUNBUFFERED='1',
               **{domains.EXCLUSIVE_ENV: str(domain)})
    os.environ.update(env)
    results: dict[str, list[dict]] = {'external': [], 'controller_node': []}
    try:
        for _ in range(args.runs):
            for name in results:
                with tempfile.TemporaryDirectory() as tmp:
                    results[name].append(one_run(name == 'external', args.duration, Path(tmp),
                                                 env))
                print(name, results[name][-1], flush=True)
    finally:
        lock.close()
    print('| controller | ticks | run wall time s (median) | ticks/s (median) |')
    print('|---|---|---|---|')
    for name, runs in results.items():
        print(f'| {name} | {runs[0]["ticks"]} | '
              f'{statistics.median(r["wall_time"] for r in runs):.2f} | '
              f'{statistics.median(r["ticks_per_s"] for r in runs):.0f} |')
    return 0


if __name__ == '__main__':
    sys.exit(main())
