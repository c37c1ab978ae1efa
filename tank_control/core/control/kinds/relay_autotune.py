"""Controller kind ``relay_autotune``: a PID with a relay auto-tuning test ([DeadTimeNotes] §1.3, [Precup2013]
§3.2–3.3) and the design, preview, apply, verify and revert of its gains. Commands
``~/start_autotune``, ``~/abort_autotune``, ``~/apply_autotune``, ``~/revert_gains``; the
results are written back to the read-only ``autotune.*`` parameters, the gains and the
``robustness.*`` analysis of the running loop on the identified model."""
from __future__ import annotations

from dataclasses import asdict
from typing import Any

from tank_control.core.analysis.linear import LinearController, pid_controller
from tank_control.core.control.kinds import base
from tank_control.core.control.kinds.base import ControllerKind, LoopWatch, Settings
from tank_control.core.control.pid import PidConfig
from tank_control.core.control.relay_autotune import (DESIGN_FIELDS, RULES_IPDT, RULES_MODEL,
                                                      RULES_ULTIMATE, TESTING, AutotuneCommand,
                                                      AutotuneConfig, AutotuneResults,
                                                      RelayAutotuner, design_arguments)
from tank_control.core.tuning.model import ProcessModel
from tank_control.core.tuning.rules import tune

COMMANDS = ('start_autotune', 'abort_autotune', 'apply_autotune', 'revert_gains')


def identified_model(values: base.Values) -> ProcessModel | None:
    """The model the auto-tuner reported in its result parameters (``autotune.model_*``)."""
    kind = values.get('autotune.model_kind', 'none')
    if kind not in ('fopdt', 'ipdt', 'sopdt'):
        return None
    model = ProcessModel(kind, abs(values['autotune.model_gain']),
                         values['autotune.model_dead_time'],
                         values['autotune.model_time_constant'] if kind != 'ipdt' else 0.0,
                         values.get('autotune.model_time_constant2', 0.0) if kind == 'sopdt'
                         else 0.0)
    return None if model.reason() else model


def summary(values: base.Values) -> str:
    """One line of what the last successful test found, from the result parameters, or '' before
    one: ``Ku 118.3, Tu 10.82 s (4 cycles); model fopdt K 0.0504, T 10.08 s, L 2.997 s
    (time_domain); gains (zn_001) kp 70.96, ti 5.411 s, td 1.299 s, b 1, c 1`` (the proposal,
    applied or not; an SOPDT gives T1 and T2, a step test says so instead of the cycles; the
    transient points ``… s record) 0.1452 rad/s 0.01653∠-82.1°, …`` before the gains)."""
    ku, tu = float(values.get('autotune.ku', 0.0)), float(values.get('autotune.tu', 0.0))
    if ku <= 0 or tu <= 0:
        return ''
    method = values.get('autotune.model_method', 'none')
    text = f"Ku {ku:.4g}, Tu {tu:.4g} s" + (
        ' (of the step model)' if str(method).startswith('step_')
        else f" ({values.get('autotune.cycles', 0)} cycles)")
    kind = values.get('autotune.model_kind', 'none')
    if kind in ('fopdt', 'sopdt'):
        lags = f"T {values['autotune.model_time_constant']:.4g} s"
        if kind == 'sopdt':
            lags = (f"T1 {values['autotune.model_time_constant']:.4g} s, "
                    f"T2 {values['autotune.model_time_constant2']:.4g} s")
        text += (f"; model {kind} K {values['autotune.model_gain']:.4g}, {lags}, "
                 f"L {values['autotune.model_dead_time']:.4g} s ({method})")
    elif kind == 'ipdt':
        text += (f"; model ipdt k1 {values['autotune.model_gain']:.4g} 1/s, "
                 f"L {values['autotune.model_dead_time']:.4g} s")
    omega = [w for w in values.get('autotune.transient_omega', [0.0]) if w > 0]
    if omega:
        points = ', '.join(f'{w:.4g} rad/s {g:.4g}∠{p:.1f}°' for w, g, p in zip(
            omega, values['autotune.transient_gain'], values['autotune.transient_phase']))
        text += (f"; G(jω) from the transient (α {values['autotune.transient_alpha_used']:.3g}/s, "
                 f"{values['autotune.transient_record']:.4g} s record) {points}")
    if float(values.get('autotune.proposed_kp', 0.0)) > 0:
        text += (f"; gains ({values.get('autotune.rule', '?')}) "
                 f"kp {values['autotune.proposed_kp']:.4g}, ti {values['autotune.proposed_ti']:.4g} s, "
                 f"td {values['autotune.proposed_td']:.4g} s, b {values['autotune.proposed_b']:.3g}, "
                 f"c {values['autotune.proposed_c']:.3g}")
    return text


def build(settings: Settings) -> RelayAutotuner:
    tuner = RelayAutotuner(settings.config, settings.autotune,
                           output_name=settings.channels.output_names[0],
                           input_name=settings.channels.input_names[0])
    tuner.ms_max = settings.robustness.ms_max
    base.attached(tuner).loop_watch = LoopWatch(None, settings.robustness.ms_max)
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
    (``autotune.state`` …) change nothing. A design setting (``autotune.rule``, …) re-derives
    the gains from the stored model.
    """
    pid_changed = any(k in changed and getattr(tuner.pid.config, k) != v
                      for k, v in asdict(settings.config).items())
    new_cfg = settings.autotune
    if (pid_changed or new_cfg != tuner.config) and tuner.state in TESTING:
        tuner.abort('parameters changed during the test')
    base.set_changed_gains(tuner.pid, settings.config, changed)
    tuner.ms_max = settings.robustness.ms_max
    base.attached(tuner).loop_watch.ms_max = settings.robustness.ms_max
    if new_cfg != tuner.config:
        tuner.configure(new_cfg)
    base.apply_mode(tuner.pid, tuner.pid.mode, settings, changed)
    if 'autotune.start' in changed and settings.command.start:
        tuner.start()
    return True


def design_reason(settings: Settings) -> str | None:
    """A design setting changed while a model is stored: the rule must apply to that model."""
    values = settings.values
    if not any(f'autotune.{name}' in settings.given for name in DESIGN_FIELDS):
        return None
    cfg = settings.autotune
    model = identified_model(values)
    try:
        if cfg.rule in RULES_ULTIMATE:
            if values['autotune.ku'] > 0:
                tune(cfg.rule, cfg.kind, ku=values['autotune.ku'], tu=values['autotune.tu'])
            return None
        if model is None:
            return None
        if cfg.rule in RULES_IPDT and model.kind != 'ipdt':
            return (f'autotune.rule: {cfg.rule} needs an integrating (IPDT) model, the stored '
                    f'model is {model.kind}')
        if cfg.rule in RULES_MODEL:
            tune(cfg.rule, cfg.kind, **design_arguments(model, cfg, settings.config))
        elif cfg.rule not in RULES_IPDT:
            if model.kind != 'fopdt':
                return (f'autotune.rule: {cfg.rule} needs an FOPDT model, the stored model is '
                        f'{model.kind}')
            tune(cfg.rule, cfg.kind, gain=model.gain, time_constant=model.time_constant,
                 dead_time=model.dead_time)
        else:
            tune(cfg.rule, cfg.kind, gain=model.gain, dead_time=model.dead_time)
    except ValueError as exc:
        text = str(exc).removeprefix('tune: ')
        return f'autotune.rule {cfg.rule!r} with autotune.kind {cfg.kind!r}: {text}'
    return None


def reason(settings: Settings) -> str | None:
    """SISO relations, a design the stored model allows, the robustness guard on it."""
    return (base.siso_reason(settings) or design_reason(settings)
            or base.guard_reason(settings, identified_model(settings.values), settings.config))


def results(tuner: RelayAutotuner) -> dict[str, Any]:
    """The tuner's results, ``robustness.*`` of the running loop and [DeadTimeNotes]'s sampling advice on
    the identified model."""
    watch = base.attached(tuner).loop_watch
    watch.model = tuner.model
    return {**tuner.results(), **watch.values(tuner.pid.config),
            **watch.sampling(tuner.pid.config.sample_time)}


def linear(settings: Settings) -> LinearController:
    """The implemented PID's discrete transfer function (the gains in force), and the model
    the auto-tuner identified."""
    return pid_controller(settings.config, (('identified', identified_model(settings.values)),))


KIND = ControllerKind(
    name='relay_autotune',
    description='PID with relay auto-tuning ([DeadTimeNotes] §1.3, [Precup2013] §3.2–3.3)',
    config=PidConfig,
    groups=(base.channels(('y',), ('u',)), base.MODE, base.fail_safe(), base.warm_start(),
            base.group('autotune', AutotuneConfig), base.group('command', AutotuneCommand),
            base.group('results', AutotuneResults), base.ROBUSTNESS, base.ROBUSTNESS_RESULTS,
            base.SAMPLING_RESULTS),
    build=build, update=update, reason=reason, results=results, state='autotune.state',
    commands=base.forwarded_commands(COMMANDS),
    gains=('kp', 'ti', 'td', 'b', 'c', 'n'), input_limits=base.scalar_limits, summary=summary,
    linear=linear,
)
