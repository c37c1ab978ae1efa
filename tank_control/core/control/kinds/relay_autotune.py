"""Controller kind ``relay_autotune``: a PID with a relay auto-tuning test (001 §1.3, 004
§3.2–3.3). Commands ``~/start_autotune``, ``~/abort_autotune``; the results are written back
to the read-only ``autotune.*`` parameters and the gains."""
from __future__ import annotations

from dataclasses import asdict

from tank_control.core.control.kinds import base
from tank_control.core.control.kinds.base import ControllerKind, Settings
from tank_control.core.control.pid import PidConfig
from tank_control.core.control.relay_autotune import (TESTING, AutotuneCommand, AutotuneConfig,
                                                      AutotuneResults, RelayAutotuner)

COMMANDS = ('start_autotune', 'abort_autotune')


def build(settings: Settings) -> RelayAutotuner:
    tuner = RelayAutotuner(settings.config, settings.autotune,
                           output_name=settings.channels.output_names[0],
                           input_name=settings.channels.input_names[0])
    if settings.mode.mode == 'manual':
        tuner.pid.set_manual(float(settings.mode.manual_output))
    if settings.command.start:
        tuner.start()
    return tuner


def update(tuner: RelayAutotuner, settings: Settings, changed: frozenset[str]) -> bool:
    """Apply accepted changes in place, bumplessly (never rebuild).

    A change of a PID or test setting while a test runs aborts the test first (reason
    'parameters changed during the test'). ``autotune.start`` = true starts a test. Only PID
    settings named in ``changed`` are applied: the running gains may be tuned ones that the
    parameters show only once the node has written the results back. Result parameters
    (``autotune.state`` …) change nothing.
    """
    pid_changed = any(k in changed and getattr(tuner.pid.config, k) != v
                      for k, v in asdict(settings.config).items())
    new_cfg = settings.autotune
    if (pid_changed or new_cfg != tuner.config) and tuner.state in TESTING:
        tuner.abort('parameters changed during the test')
    base.set_changed_gains(tuner.pid, settings.config, changed)
    if new_cfg != tuner.config:
        tuner.configure(new_cfg)
    base.apply_mode(tuner.pid, tuner.pid.mode, settings, changed)
    if 'autotune.start' in changed and settings.command.start:
        tuner.start()
    return True


KIND = ControllerKind(
    name='relay_autotune',
    description='PID with relay auto-tuning (001 §1.3, 004 §3.2–3.3)',
    config=PidConfig,
    groups=(base.channels(('y',), ('u',)), base.MODE, base.fail_safe(), base.warm_start(),
            base.group('autotune', AutotuneConfig), base.group('command', AutotuneCommand),
            base.group('results', AutotuneResults)),
    build=build, update=update, reason=base.siso_reason,
    results=lambda tuner: tuner.results(), state='autotune.state',
    commands={name: (lambda tuner, name=name: tuner.command(name)) for name in COMMANDS},
    gains=('kp', 'ti', 'td', 'b', 'c', 'n'), input_limits=base.scalar_limits,
)
