"""The dashboard's robustness panel: Bode, Nyquist and margins of the running SISO loop.

Pure (no rclpy): from the plant node's and the controller node's parameter values to one
JSON-safe message. The loop is the implemented one, as ``tank-control analyze`` and
``analysis.png`` describe it (``core/scenario_loops.py``): the controller kind's discrete
transfer function on the exact ZOH model of the plant kind's linear description at the
controller's sample time, exact dead time ([Checks] §2; [Ikonen]). Any kinds that describe themselves
(``ControllerKind.linear``, ``PlantKind.linear``; docs/extending.md). Frequencies in rad/s,
phase in degrees, delay margin in s.
"""
from __future__ import annotations

import json
import math
import threading
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from tank_control.core.analysis import frequency as fr
from tank_control.core.analysis.linear import frequency_scale
from tank_control.core.scenario_loops import LoopCase, describe_loop
from tank_control.core.control.pid import PidConfig
from tank_control.core.params import ConfigError
from tank_control.core.scenario import controller_setup, plant_setup
from tank_control.core.tuning.model import ProcessModel
from tank_control.dashboard.values import jsonable

#: Points of the Bode and Nyquist curves sent to the page.
CURVE_POINTS = 600
#: The margins shown (fields of ``robustness.LoopReport``).
MARGIN_KEYS = ('stable', 'gain_margin', 'phase_margin', 'ms', 'mt', 'delay_margin', 'wc',
               'w180')


def _unavailable(reason: str) -> dict[str, Any]:
    return {'available': False, 'reason': reason, 'w': [], 'cases': []}


def _grid(loop: fr.FrequencyResponse, wu: float) -> np.ndarray:
    """As ``analysis.png``: from ``wu``/200 to the Nyquist frequency π/h [rad/s]."""
    hi = math.pi / loop.sample_time * (1 - 1e-9)
    lo = min(wu / 200.0, hi / 1e4)
    return np.logspace(math.log10(lo), math.log10(hi), CURVE_POINTS)


def _case(case: LoopCase, w: np.ndarray) -> dict[str, Any]:
    """One model's margins (:meth:`LoopCase.report`) and curves of L = C·G on the grid
    ``w``."""
    loop = case.controller.feedback * case.model.response(case.controller.sample_time)
    report = case.report()
    _, mag, phase = fr.bode(loop, w)
    values = loop(w)
    return {'label': case.label,
            'margins': {key: jsonable(bool(getattr(report, key)) if key == 'stable'
                                      else float(getattr(report, key))) for key in MARGIN_KEYS},
            'mag': jsonable(mag), 'phase': jsonable(phase),
            're': jsonable(values.real), 'im': jsonable(values.imag)}


def loop_analysis(plant_values: Mapping[str, Any] | None,
                  controller_values: Mapping[str, Any] | None) -> dict[str, Any]:
    """The panel's message: ``available``, ``reason`` (one line when not available),
    ``controller`` (one line of its settings) and per case (the plant's model, the models the
    controller carries) ``label``, ``margins`` and the curves ``mag``, ``phase`` (Bode of
    L = C·G) and ``re``, ``im`` (Nyquist of L) on the common grid ``w`` [rad/s]. Any pair of
    kinds that describe themselves (``core/scenario_loops.describe_loop``) is analysed."""
    if controller_values is None or plant_values is None:
        missing = 'controller' if controller_values is None else 'plant'
        return {**_unavailable(f'no {missing} node (yet): its parameters are needed'),
                'waiting': True}
    try:
        plant_setup(plant_values)                  # a bad value: ConfigError with its reason
        found, reason = describe_loop(plant_values, controller_values)
        if not found or not found[0].label.startswith('plant'):
            return _unavailable(reason or 'the plant has no linear model of these settings')
        first = found[0]
        ctrl = first.controller
        w = _grid(ctrl.feedback * first.model.response(ctrl.sample_time),
                  frequency_scale(first.model))
        cases = [_case(case, w) for case in found]
    except (ConfigError, ValueError, ZeroDivisionError, ArithmeticError) as exc:
        return _unavailable(f'the loop cannot be analysed: {exc}')
    return {'available': True, 'reason': '',
            'controller': f'{ctrl.describe}; discrete loop, h = {ctrl.sample_time:.4g} s; '
                          'exact dead time',
            'w': jsonable(w), 'cases': cases}


class RobustnessWorker:
    """Computes :func:`loop_analysis` in a thread of its own (the node's executor is never held
    up by it), the latest request winning; ``publish`` gets each new message (any thread),
    ``latest`` is the last one (for a page that connects)."""

    def __init__(self, publish: Callable[[dict[str, Any]], None]) -> None:
        self._publish = publish
        self._cond = threading.Condition()
        self._pending: tuple[Any, Any] | None = None
        self._key: str | None = None
        self._stopped = False
        self.latest: dict[str, Any] = _unavailable('waiting for the plant and controller nodes')
        self._thread = threading.Thread(target=self._run, name='dashboard-robustness',
                                        daemon=True)
        self._thread.start()

    def submit(self, plant_values: Mapping[str, Any] | None,
               controller_values: Mapping[str, Any] | None) -> None:
        """Analyse these values unless they equal the last ones submitted."""
        key = json.dumps([plant_values, controller_values], sort_keys=True, default=str)
        with self._cond:
            if key == self._key:
                return
            self._key = key
            self._pending = (plant_values, controller_values)
            self._cond.notify()

    def stop(self, timeout: float = 10.0) -> None:
        with self._cond:
            self._stopped = True
            self._cond.notify()
        self._thread.join(timeout)

    def _run(self) -> None:
        while True:
            with self._cond:
                while self._pending is None and not self._stopped:
                    self._cond.wait()
                if self._stopped:
                    return
                pending = self._pending
                assert pending is not None       # the wait ends on a request or a stop
                plant_values, controller_values = pending
                self._pending = None
            try:
                result = loop_analysis(plant_values, controller_values)
            except Exception as exc:     # noqa: BLE001 - the page gets the reason, the thread lives
                result = _unavailable(f'the loop cannot be analysed: {exc}')
            message = {'type': 'robustness', **result}
            self.latest = message
            self._publish(message)


#: Most points of a predicted step response sent to the page.
STEP_POINTS = 300


def tuning_preview(plant_values: Mapping[str, Any] | None,
                   controller_values: Mapping[str, Any] | None,
                   changes: Mapping[str, Any]) -> dict[str, Any]:
    """The tuning view's prediction for the controller's values with ``changes`` (e.g. a
    tuning rule and its setting), before anything is applied: the gains the controller would
    derive, the margins of :func:`loop_analysis` (the robustness panel's and ``tank-control
    analyze``'s numbers for those gains) and the predicted unit setpoint and load steps on
    the plant's model (``analysis.robustness.predict``: no output limits, from rest)."""
    from tank_control.core.analysis.robustness import predict

    if controller_values is None:
        return {'available': False, 'waiting': True,
                'reason': 'no controller node (yet): its parameters are needed'}
    candidate = {**controller_values, **changes}
    analysis = loop_analysis(plant_values, candidate)
    if not analysis['available']:
        # ``waiting``: a node's parameters are not known yet; the page asks again once the
        # robustness panel's analysis is available
        return {'available': False, 'reason': analysis['reason'],
                'waiting': bool(analysis.get('waiting'))}
    try:
        config = controller_setup(candidate, given=()).settings.config
    except (ConfigError, ValueError) as exc:
        return {'available': False, 'reason': str(exc)}
    gains = {name: jsonable(float(getattr(config, name))) for name in
             ('kp', 'ti', 'td', 'n', 'b', 'c', 'sample_time') if hasattr(config, name)}
    out: dict[str, Any] = {'available': True, 'reason': '', 'gains': gains,
                           'label': analysis['cases'][0]['label'],
                           'margins': analysis['cases'][0]['margins']}
    try:
        found, _ = describe_loop(plant_values, candidate)
        model = found[0].model if found else None
        if isinstance(model, ProcessModel) and isinstance(config, PidConfig):
            prediction = predict(model, config)
            every = max(1, len(prediction.t) // STEP_POINTS)
            out.update(t=jsonable(prediction.t[::every]),
                       setpoint=jsonable(prediction.setpoint[::every]),
                       load=jsonable(prediction.load[::every]),
                       overshoot=jsonable(prediction.overshoot),
                       settling_time=jsonable(prediction.settling_time))
        else:
            out['step_reason'] = ('no step prediction: it is simulated for a PID on a '
                                  'process model (ipdt, fopdt, sopdt)')
    except (ConfigError, ValueError, ZeroDivisionError) as exc:
        out['step_reason'] = f'no step prediction: {exc}'
    return out
