"""The dashboard's robustness panel: Bode, Nyquist and margins of the running SISO loop.

Pure (no rclpy): from the plant node's and the controller node's parameter values to one
JSON-safe message. The loop is the implemented one, as ``tank-control analyze`` and
``analysis.png`` describe it (``harness/analysis.py``: :func:`loop_cases`, ``loop_report``):
``Pid2Dof`` (``frequency.pid_feedback_discrete``) on the exact ZOH model of the plant at the
controller's sample time, exact dead time (SPEC §3; 002). Plants: ``fopdt``, ``ipdt``,
``sopdt`` (through their process model) and ``transfer_function`` (``frequency.rational_zoh``);
controllers ``pid`` and ``relay_autotune``. Frequencies in rad/s, phase in degrees, delay
margin in s.
"""
from __future__ import annotations

import json
import math
import threading
from collections.abc import Callable, Mapping
from dataclasses import replace
from typing import Any

import numpy as np

from tank_control.core.analysis import frequency as fr
from tank_control.core.control.pid import PidConfig
from tank_control.core.params import ConfigError
from tank_control.core.scenario import controller_setup, plant_setup
from tank_control.dashboard.values import jsonable
from tank_control.core.analysis.loops import PID_KINDS, loop_cases

#: Points of the Bode and Nyquist curves sent to the page.
CURVE_POINTS = 600
#: The margins shown (keys of ``frequency.controller_report``).
MARGIN_KEYS = ('stable', 'gain_margin', 'phase_margin', 'ms', 'mt', 'delay_margin', 'wc',
               'w180')


def _unavailable(reason: str) -> dict[str, Any]:
    return {'available': False, 'reason': reason, 'w': [], 'cases': []}


def _grid(loop: fr.FrequencyResponse, wu: float) -> np.ndarray:
    """As ``analysis.png``: from ``wu``/200 to the Nyquist frequency π/h [rad/s]."""
    hi = math.pi / loop.sample_time * (1 - 1e-9)
    lo = min(wu / 200.0, hi / 1e4)
    return np.logspace(math.log10(lo), math.log10(hi), CURVE_POINTS)


def _case(label: str, ctrl: fr.FrequencyResponse, plant: fr.FrequencyResponse,
          setpoint: fr.FrequencyResponse, w: np.ndarray) -> dict[str, Any]:
    """One model's margins (``frequency.controller_report``, as ``loop_report``) and curves
    of L = C·G on the grid ``w``."""
    loop = ctrl * plant
    report = fr.controller_report(ctrl, plant, setpoint)
    _, mag, phase = fr.bode(loop, w)
    values = loop(w)
    return {'label': label,
            'margins': {key: jsonable(bool(report[key]) if key == 'stable'
                                      else float(report[key])) for key in MARGIN_KEYS},
            'mag': jsonable(mag), 'phase': jsonable(phase),
            're': jsonable(values.real), 'im': jsonable(values.imag)}


def _pid(config: PidConfig) -> tuple[fr.FrequencyResponse, fr.FrequencyResponse]:
    """The controller's feedback (−U/Y) and setpoint (U/R) responses, as ``loop_report``."""
    h, kp = config.sample_time, abs(config.kp)
    return (fr.pid_feedback_discrete(kp, config.ti, config.td, config.n, sample_time=h),
            fr.pid_setpoint_discrete(kp, config.ti, config.td, config.n, config.b, config.c,
                                     sample_time=h))


def loop_analysis(plant_values: Mapping[str, Any] | None,
                  controller_values: Mapping[str, Any] | None) -> dict[str, Any]:
    """The panel's message: ``available``, ``reason`` (one line when not available), the
    controller's settings ``pid`` and per case (the plant's model, the controller's own model)
    ``label``, ``margins`` and the curves ``mag``, ``phase`` (Bode of L = C·G) and ``re``,
    ``im`` (Nyquist of L) on the common grid ``w`` [rad/s]."""
    if controller_values is None or plant_values is None:
        missing = 'controller' if controller_values is None else 'plant'
        return _unavailable(f'no {missing} node (yet): its parameters are needed')
    kind = controller_values.get('controller')
    plant_kind = plant_values.get('plant', 'fopdt')
    if kind not in PID_KINDS:
        return _unavailable(f'controller {kind}: the frequency analysis describes a SISO loop '
                            f'of a PID-family controller ({", ".join(PID_KINDS)})')
    try:
        setup = controller_setup(controller_values, given=())
        config = setup.settings.config
        if not isinstance(config, PidConfig):
            return _unavailable(f'controller {kind}: not a PID configuration')
        config = replace(config, kp=abs(config.kp), direct_action=False)
        ctrl, setpoint = _pid(config)
        if plant_kind == 'transfer_function':
            model = plant_setup(plant_values).model
            plant = fr.rational_zoh(model.num, model.den, model.dead_time, config.sample_time)
            try:
                wu = fr.ultimate_point(fr.plant_response(model)).wu
            except ValueError:                     # no phase crossover: the slowest corner
                wu = min(c for c in (ctrl * plant).corners if c > 0)
            w = _grid(ctrl * plant, wu)
            cases = [_case(f'plant (transfer_function, L={model.dead_time:.6g} s)', ctrl,
                           plant, setpoint, w)]
        else:
            plant_setup(plant_values)              # a bad value: ConfigError with its reason
            found = loop_cases({'plant': plant_values}, controller_values)
            if not found or not found[0].label.startswith('plant'):
                return _unavailable(
                    f'plant {plant_kind}: the frequency analysis describes fopdt, ipdt, sopdt '
                    '(critically damped or two lags) with a non-zero gain and '
                    'transfer_function plants')
            first = found[0].model
            wu = first.ultimate_point().wu if first.dead_time > 0 else 1.0
            w = _grid(ctrl * first.response(config.sample_time), wu)
            cases = [_case(case.label, ctrl, case.model.response(config.sample_time), setpoint,
                           w) for case in found]
    except (ConfigError, ValueError, ZeroDivisionError) as exc:
        return _unavailable(f'the loop cannot be analysed: {exc}')
    pid = {'kp': config.kp, 'ti': config.ti, 'td': config.td, 'n': config.n, 'b': config.b,
           'c': config.c, 'sample_time': config.sample_time}
    return {'available': True, 'reason': '', 'pid': {k: jsonable(v) for k, v in pid.items()},
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
                plant_values, controller_values = self._pending
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
        return _unavailable('no controller node (yet): its parameters are needed')
    candidate = {**controller_values, **changes}
    analysis = loop_analysis(plant_values, candidate)
    if not analysis['available']:
        return {'available': False, 'reason': analysis['reason']}
    out: dict[str, Any] = {'available': True, 'reason': '', 'gains': analysis['pid'],
                           'label': analysis['cases'][0]['label'],
                           'margins': analysis['cases'][0]['margins']}
    try:
        config = controller_setup(candidate, given=()).settings.config
        found = loop_cases({'plant': dict(plant_values or {})}, candidate)
        if found and isinstance(config, PidConfig):
            prediction = predict(found[0].model, config)
            every = max(1, len(prediction.t) // STEP_POINTS)
            out.update(t=jsonable(prediction.t[::every]),
                       setpoint=jsonable(prediction.setpoint[::every]),
                       load=jsonable(prediction.load[::every]),
                       overshoot=jsonable(prediction.overshoot),
                       settling_time=jsonable(prediction.settling_time))
    except (ConfigError, ValueError, ZeroDivisionError) as exc:
        out['step_reason'] = f'no step prediction: {exc}'
    return out
