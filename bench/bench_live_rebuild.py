"""Late samples of a wall-paced loop at 10 samples/s across heavy live work: on the sampling
path (the synchronous baseline) against off it (controller_node in wall mode).

* relay: the relay tuner (rule ms: the time-domain fit and the Ms-constrained design) on a
  FOPDT (K 0.05·(1 + i/100) in run i: no cached design, T 2 s, L 0.6 s), h = 0.1 s,
  ``autotune.design_time`` 0 (the default).
  Baseline: the identification and design inside the sample that completes the data (the
  in-process / lockstep behaviour); wall: ``wall_clock`` set, as controller_node does in wall
  mode — the design runs in a worker process, the first sample after it is ready switches.
* mpcs: MPCS (QP, sample time 1 s) on the mixing tank, stepped 10 times per second of wall
  time (a 100-ms budget per sample, as a 10 Hz loop), ``mpcs.horizon`` 600 -> 2000 accepted
  after sample 20. Baseline: the change built and tried when accepted, between two samples
  in the sampling thread (the node's parameter callback on its single-threaded executor, as
  before); wall: built in the worker (``nodes/live_rebuild.LiveRebuild``), the running MPCS
  samples on, the first sample after it is ready switches.
* tuning.ms_target: a PID with ``tuning.rule`` ms on a FOPDT (K 1.3·(1 + i/100) in run i: no
  cached design, T 2 s, L 0.6 s), h = 0.1 s, ``tuning.ms_target`` 1.4 -> 1.6 accepted after
  sample 20. Baseline: the design in the parameter callback (derive and check, then the change
  prepared), between two samples in the sampling thread; wall: checked without the design, the
  design in the worker thread (``nodes/live_derive.LiveDerive``), the first sample after it is
  ready takes the derived gains.

A sample is late when it ends after the next sample instant. Baseline and wall runs
alternate; medians of ``--runs`` each.

    PYTHONPATH=$PWD .venv/bin/python bench/bench_live_rebuild.py --runs 3
"""
from __future__ import annotations

import argparse
import copy
import statistics
import time

import numpy as np

from tank_control.core.control.kinds import registry
from tank_control.core.control.kinds.base import resolve
from tank_control.core.tuning.model import ProcessModel
from tank_control.core.scenario import controller_setup
from tank_control.nodes import live_derive
from tank_control.nodes.live_rebuild import LiveRebuild

H = 0.1          # s of wall time per sample
RELAY = {'kp': 20.0, 'ti': 3.0, 'u_min': 0.0, 'u_max': 10000.0, 'sample_time': H,
         'autotune.relay_amplitude': 200.0, 'autotune.settle_time': 1.0,
         'autotune.settle_band': 0.5, 'autotune.max_amplitude': 50.0,
         'autotune.rule': 'ms', 'autotune.kind': 'pid'}


class Pacer:
    """Sample instants every ``H`` s of wall time; counts the samples ending late."""

    def __init__(self) -> None:
        self.start = time.monotonic()
        self.late = 0
        self.longest = 0.0

    def wait(self, k: int) -> float:
        instant = self.start + k * H
        pause = instant - time.monotonic()
        if pause > 0:
            time.sleep(pause)               # pacing, as a wall timer
        return instant

    def done(self, instant: float, began: float) -> None:
        end = time.monotonic()
        self.longest = max(self.longest, end - began)
        self.late += end > instant + H


def relay_run(wall: bool, seconds: float, variant: int) -> tuple[int, float, str]:
    """``variant``: the plant's gain 0.05·(1 + variant/100), a new design each run (the
    rules cache their designs: core/tuning/rules.py)."""
    controller = registry.make_controller('relay_autotune', RELAY)
    controller.wall_clock = wall
    plant = ProcessModel('fopdt', 0.05 * (1 + variant / 100), 0.6, 2.0).plant()
    r = np.array([100.0])
    controller.start()
    pacer = Pacer()
    for k in range(int(seconds / H)):
        instant = pacer.wait(k)
        began = time.monotonic()
        u = controller.step(k * H, plant.outputs(), r, np.array([]))
        pacer.done(instant, began)
        plant.step(u, np.array([0.0]), H)
    return pacer.late, pacer.longest, controller.state


def mpcs_run(wall: bool, samples: int) -> tuple[int, float, str]:
    kind = registry.get_kind('mpcs')
    values = {'mpcs.solver': 'qp'}
    controller = registry.build(kind, resolve(kind, values))
    changed = frozenset({'mpcs.horizon'})
    settings = resolve(kind, {**values, 'mpcs.horizon': 2000}, given=())
    y, r, d = np.array([81.0, 2115.0 / 63.0]), np.array([82.0, 34.0]), np.full(2, np.nan)
    controller.reset(y, np.array([controller.config.op_F_H, controller.config.op_F_Cin]))
    pacer = Pacer()
    rebuild, prepared, u, switched = None, None, None, -1
    for k in range(samples):
        instant = pacer.wait(k)
        began = time.monotonic()
        t = float(k)          # the MPCS's own time: 1-s samples
        if rebuild is not None and rebuild.done():
            controller, u = rebuild.switch(controller, -1, t, y, r, d)
            rebuild, switched = None, k
        elif prepared is not None:
            controller, u = prepared.take_effect(controller, t, y, r, d)
            prepared, switched = None, k
        else:
            u = np.asarray(controller.step(t, y, r, d), dtype=float)
        pacer.done(instant, began)
        if k == 20:            # the change accepted between samples 20 and 21
            trial = (t, y, r, d)
            if wall:
                rebuild = LiveRebuild(kind, copy.deepcopy(controller), settings, changed,
                                      {'mpcs.horizon': 600}, gen=k, trial=trial, u_last=u)
            else:
                prepared = registry.prepare_change(kind, controller, settings, changed,
                                                   trial=trial, u_last=u)
    state = f'horizon {controller.config.horizon} from sample {switched}'
    return pacer.late, pacer.longest, state


def pid_run(wall: bool, samples: int, variant: int) -> tuple[int, float, str]:
    values = {'controller': 'pid', 'sample_time': H, 'tuning.rule': 'ms',
              'tuning.gain': 1.3 * (1 + variant / 100), 'tuning.dead_time': 0.6,
              'tuning.time_constant': 2.0}
    kind = registry.get_kind('pid')
    values = {**controller_setup(values).settings.values, 'controller': 'pid'}
    controller = registry.build(kind, controller_setup(values).settings)
    names = frozenset(n for n in values if n != 'controller')
    changed = frozenset({'tuning.ms_target'})
    new = {**values, 'tuning.ms_target': 1.6}
    y, r, d = np.array([1.0]), np.array([1.0]), np.array([])
    controller.reset(y, np.array([2.0]))
    pacer = Pacer()
    job, prepared, switched = None, None, -1
    for k in range(samples):
        instant = pacer.wait(k)
        began = time.monotonic()
        t = k * H
        if job is not None and job.done():
            gains = job.gains()        # the node writes them, then takes them at this sample
            settings = controller_setup({**new, **gains}, given=()).settings
            prepared = registry.prepare_change(kind, controller, settings,
                                               changed | frozenset(gains))
            job = None
        if prepared is not None:
            controller, u = prepared.take_effect(controller, t, y, r, d)
            prepared, switched = None, k
        else:
            controller.step(t, y, r, d)
        pacer.done(instant, began)
        if k == 20:            # the change accepted between samples 20 and 21
            accepting = time.monotonic()
            if wall:
                controller_setup(live_derive.without_design(new), given=changed)
                job = live_derive.LiveDerive(kind, names, new, changed,
                                             {'tuning.ms_target': 1.4})
            else:
                settings = controller_setup(new, given=changed).settings
                prepared = registry.prepare_change(kind, controller, settings, changed,
                                                   trial=(t, y, r, d), u_last=np.array([2.0]))
            blocked = time.monotonic() - accepting
    state = (f'kp {controller.pid.config.kp:.3g} from sample {switched}, the sampling thread '
             f'busy {blocked * 1e3:.0f} ms accepting')
    return pacer.late, pacer.longest, state


def report(what: str, results: list[tuple[int, float, str]]) -> None:
    lates = [r[0] for r in results]
    longest = [r[1] for r in results]
    print(f'{what}: late samples median {statistics.median(lates):g} {lates}, longest step '
          f'median {statistics.median(longest) * 1e3:.1f} ms '
          f'{[round(x * 1e3, 1) for x in longest]}, end {[r[2] for r in results]}',
          flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--runs', type=int, default=3)
    parser.add_argument('--seconds', type=float, default=40.0, help='wall time of a relay run')
    parser.add_argument('--mpcs-samples', type=int, default=200)
    parser.add_argument('--pid-samples', type=int, default=100)
    parser.add_argument('--only', choices=('relay', 'mpcs', 'pid'))
    args = parser.parse_args()
    if args.only in (None, 'relay'):
        runs = {False: [], True: []}
        for i in range(args.runs):
            for wall in (False, True):
                runs[wall].append(relay_run(wall, args.seconds, 2 * i + wall))
        report('relay completion, on the sampling path', runs[False])
        report('relay completion, wall mode (worker process)', runs[True])
    if args.only in (None, 'pid'):
        runs = {False: [], True: []}
        for i in range(args.runs):
            for wall in (False, True):
                runs[wall].append(pid_run(wall, args.pid_samples, 2 * i + wall))
        report('tuning.ms_target 1.4 -> 1.6 (rule ms), on the sampling path', runs[False])
        report('tuning.ms_target 1.4 -> 1.6 (rule ms), wall mode (worker thread)', runs[True])
    if args.only in (None, 'mpcs'):
        runs = {False: [], True: []}
        for _ in range(args.runs):
            for wall in (False, True):
                runs[wall].append(mpcs_run(wall, args.mpcs_samples))
        report('mpcs.horizon 600 -> 2000, on the sampling path', runs[False])
        report('mpcs.horizon 600 -> 2000, wall mode (worker thread)', runs[True])


if __name__ == '__main__':
    main()
