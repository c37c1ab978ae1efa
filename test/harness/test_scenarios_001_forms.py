"""[DeadTimeNotes]'s ZN experiment: which reading of its PID gives its figures (docs/scenarios.md, [DeadTimeNotes]).

[DeadTimeNotes] §1.2.2 reports "about 40 %" overshoot for a step (Fig. 1.13) and "about 3 %" for a setpoint
ramped over 25 s (Fig. 1.15) with the ZN PID kp = 70.1 (printed; Table 6.2 gives 0.6·118.2 =
70.92), T_I = 5.5 s, T_D = 1.32 s. The 40 % is what it expects from the damping ζ = 0.25 it
gives for its table (it says to expect about 40 % of the P and the PID alike); the 3 % is read
from its figure.

* The table's gains in the ideal form of [Viteckova] eq. 19 leave ≥ 7 % with the ramp and overshoot a
  step by > 50 %, whichever detail we vary: the printed kp, the exact ultimate point
  (117.80, 10.824 s), the derivative filter n, the series (interacting) form, or c = 0.
* [DeadTimeNotes] describes its Simulink PID block as one where "T_I = 0 makes the integral channel's
  output zero" — a parallel block K_P + T_I/s + T_D·s into which the table's 5.5 and 1.32 were
  typed as *gains*: ti = kp/5.5 s and td = 1.32/kp s in our form. Only this reading meets the
  ramp's "about 3 %"; its step overshoot (47–48 %) is near the 44 % of ζ = 0.25.
"""
from __future__ import annotations

from pathlib import Path

import pytest
from support import CONFIG

from tank_control.harness.runner import run

KP = 70.92                                  # [DeadTimeNotes] Table 6.2 with Ku = 118.2: 0.6·Ku
TI, TD = 5.5, 1.32                          # 0.5·Tu, 0.12·Tu with Tu = 11 s


def explicit(kp: float, ti: float, td: float, *extra: str) -> tuple[str, ...]:
    return ('controller.tuning.rule=none', f'controller.kp={kp}', f'controller.ti={ti}',
            f'controller.td={td}') + extra


SIMULINK_FORM = explicit(KP, KP / TI, TD / KP)
IDEAL_FORM_VARIANTS = {
    'printed kp 70.1': explicit(70.1, TI, TD),
    'exact ultimate point': ('controller.tuning.ku=117.80', 'controller.tuning.tu=10.824'),
    'filter n = 2': ('controller.n=2.0',),
    'filter n = 50': ('controller.n=50.0',),
    # kp·(1 + 1/(Ti·s))·(1 + Td·s) written in the ideal form (exact without the filter)
    'series form': explicit(KP * (1 + TD / TI), TI + TD, TI * TD / (TI + TD)),
    'derivative on y only (c = 0)': explicit(KP, TI, TD, 'controller.c=0.0'),
}


def first_steps(tmp_path: Path, overrides: tuple[str, ...]) -> tuple[dict, dict]:
    out = []
    for name in ('fopdt_zn', 'fopdt_zn_ramp'):
        result = run(CONFIG / f'{name}.yaml', tmp_path / name, overrides=overrides,
                     in_process=True, plots=False)
        out.append(result.metrics['outputs']['y']['steps'][0])
    return out[0], out[1]


def test_001_figures_are_met_with_the_gains_read_as_the_documents_parallel_block(tmp_path):
    step, ramp = first_steps(tmp_path, SIMULINK_FORM)
    assert 35.0 <= step['overshoot_pct'] <= 50.0      # "about 40 %" (ζ = 0.25: 44 %)
    assert ramp['overshoot_pct'] <= 4.0               # "about 3 %" ([DeadTimeNotes], Fig. 1.15)
    assert abs(step['ss_error']) < 0.01 and abs(ramp['ss_error']) < 0.01


@pytest.mark.parametrize('variant', list(IDEAL_FORM_VARIANTS))
def test_001_ramp_figure_is_not_met_by_the_table_gains_in_the_ideal_form(tmp_path, variant):
    step, ramp = first_steps(tmp_path, IDEAL_FORM_VARIANTS[variant])
    assert step['overshoot_pct'] > 50.0
    assert ramp['overshoot_pct'] > 7.0
