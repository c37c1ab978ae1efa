"""A costly live change of controller_node built off the sampling path (wall mode).

A change of a kind's ``slow`` parameters (e.g. ``mpcs.horizon``: new prediction and QP
matrices, up to seconds) is checked on acceptance as any change (ranges, relations), then
the controller it makes is built and tried from the last sample in a worker thread, from a
copy of the running controller taken on acceptance. The running controller keeps sampling
with its law; the first sample after the result is ready switches, bumplessly: the kind's
``adopt`` takes the new design into the running controller (as ``update`` would at that
sample), else the candidate takes over by ``reset(y, u)`` from that sample's output. A build
or trial that fails leaves the running law untouched; the node sets the parameters back and
says why (log, ``/diagnostics``, ``update_errors``).

lockstep and sim keep the change at the next sample, built on acceptance (a fixed sample:
the in-process loop gives the same trace). Units: s.
"""
from __future__ import annotations

import threading
from collections.abc import Mapping
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import numpy as np

from tank_control.core.control.kinds import registry
from tank_control.core.control.kinds.base import ControllerKind, Settings
from tank_control.core.interfaces import Controller

_WORKER: ThreadPoolExecutor | None = None
_WORKER_LOCK = threading.Lock()


def _worker() -> ThreadPoolExecutor:
    """One thread for the rebuilds of this process (numpy releases the GIL in its kernels)."""
    global _WORKER
    with _WORKER_LOCK:
        if _WORKER is None:
            _WORKER = ThreadPoolExecutor(max_workers=1, thread_name_prefix='live-rebuild')
        return _WORKER


class WorkerJob:
    """A job on this process's worker (``_future``): whether its result is there."""

    _future: Future[Any]

    def done(self) -> bool:
        return self._future.done()

    def wait(self, timeout: float | None = None) -> bool:
        """True once the result is there (tests)."""
        try:
            self._future.exception(timeout)
        except TimeoutError:
            return False
        return True


class LiveRebuild(WorkerJob):
    """One accepted change being built in the worker thread.

    ``snapshot``: a copy of the running controller taken on acceptance (the worker changes
    it, the running one is never touched there); ``gen``: the node's sample generation then
    (the running controller unchanged since: the candidate is exactly the changed running
    controller); ``old``: the values of ``changed`` the running law was made with."""

    def __init__(self, kind: ControllerKind, snapshot: Controller, settings: Settings,
                 changed: frozenset[str], old: Mapping[str, Any], gen: int,
                 trial: registry.Sample | None, u_last: np.ndarray | None) -> None:
        self.kind, self.changed, self.old, self.gen = kind, changed, dict(old), gen
        self._future: Future[registry.PreparedChange] = _worker().submit(
            registry.prepare_change, kind, snapshot, settings, changed, trial=trial,
            u_last=u_last, copy_running=False)

    def prepared(self) -> registry.PreparedChange:
        """The built change; ``ValueError`` with the reason it was refused."""
        return self._future.result()

    def switch(self, running: Controller, running_gen: int, t: float, y: np.ndarray,
               r: np.ndarray, d: np.ndarray) -> tuple[Controller, np.ndarray]:
        """The sample that switches to the built change: ``(controller from now on, output)``,
        the output continuous with the running law's."""
        prepared = self.prepared()
        if running_gen == self.gen:           # nothing sampled since the copy: it is exact
            return prepared.take_effect(running, t, y, r, d)
        candidate = prepared.candidate
        if (prepared.in_place and self.kind.adopt is not None
                and self.kind.adopt(running, candidate, self.changed)):
            return running, np.asarray(running.step(t, y, r, d), dtype=float)
        u = np.asarray(running.step(t, y, r, d), dtype=float)
        candidate.reset(y, u)
        candidate.step(t, y, r, d)
        return candidate, u
