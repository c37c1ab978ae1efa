"""The known cases of control performance monitoring (docs/monitoring.md) and the false-alarm
bench of the well-tuned one.

    .venv/bin/python bench/monitor_cases.py write      # (re)write config/scenarios/monitor_*.yaml
    .venv/bin/python bench/monitor_cases.py bench [N]  # N seeds (default 50) of the well-tuned case
    .venv/bin/python bench/monitor_cases.py figures    # docs/images/monitor_*.png and the table

Two plants: a lag-dominant FOPDT (K = 1, T = 20 s, L = 2 s, sampled every 0.5 s) for the
well-tuned, sluggish, aggressive and saturated loops, and a flow-like FOPDT (K = 1, T = 2 s,
L = 0.5 s, 0.1 s) with an integral-dominant PI for the sticky valve. The input u is the valve's
deviation from its operating point [% of travel], limits ±50. White measurement noise
(σ = 0.05) and a random load at the plant input (piecewise constant, a new N(0, σ_v²) value
every 5 s, drawn from ``seed``) excite every loop; a setpoint step 0 → 2 at t = 100 s (the
minimum-variance case: the noise only, a constant setpoint). The
controller carries the plant's model (``tuning.gain``, ``tuning.time_constant``,
``tuning.dead_time``; the gains are set by hand, ``tuning.rule`` none): its live loop monitor
takes the loop's dead time from it.
"""
from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
DURATION = 1200.0
LOAD_EVERY = 5.0
LAG = {'gain': 1.0, 'time_constant': 20.0, 'dead_time': 2.0, 'sample_time': 0.5}
FLOW = {'gain': 1.0, 'time_constant': 2.0, 'dead_time': 0.5, 'sample_time': 0.1}

#: name → (plant, controller gains (kp, ti; ti 0: none), actuator, load σ_v, load offset from
#: 300 s, setpoint step at 100 s (default 2), title, claim)
CASES: dict[str, dict[str, Any]] = {
    'well_tuned': dict(plant=LAG, pi=(5.0, 16.0), load=0.5,
                       title='monitor: well-tuned PI (SIMC, tau_c = L) on a lag-dominant FOPDT',
                       claim='verdict good: Harris index about 0.75, no oscillation'),
    'sluggish': dict(plant=LAG, pi=(1.0, 16.0), load=0.5,
                     title='monitor: the same loop with the PI gains divided by 5',
                     claim='verdict retune (sluggish): Harris index about 0.4, no oscillation'),
    'aggressive': dict(plant=LAG, pi=(9.0, 6.67), load=0.5,
                       title='monitor: Ziegler-Nichols step-response PI (0.9 T/(K L), 3.33 L) '
                             'on the lag-dominant FOPDT',
                       claim='verdict retune (oscillating, no stiction): period about 12 s'),
    'sticky_valve': dict(plant=FLOW, pi=(0.3, 1.5), load=0.2,
                         actuator={'actuator.stiction_s': [5.0], 'actuator.stiction_j': [2.0]},
                         title='monitor: flow loop with a sticky valve (Choudhury S = 5 %, '
                               'J = 2 %)',
                         claim='limit cycle (period about 54 s); verdict valve: stiction '
                               'suspected — do not retune'),
    'saturated': dict(plant=LAG, pi=(5.0, 16.0), load=0.5, offset=-60.0,
                      title='monitor: a load from t = 300 s that the valve cannot compensate',
                      claim='verdict saturated about 75 % of the time'),
    # white measurement noise the only disturbance, constant setpoint: the minimum-variance
    # controller does nothing (index 1); a P controller of modest gain is close to it
    # (the slow integral removes the offset a bumpless start of a P controller would keep)
    'minimum_variance': dict(plant=LAG, pi=(3.0, 40.0), load=0.0, step=0.0,
                             title='monitor: near minimum variance: PI (kp 3, Ti 40 s) on the '
                                   'lag-dominant FOPDT, white measurement noise only',
                             claim="verdict good: Harris index 0.956 = 1/sum(s_i^2) of the loop's "
                                   'sensitivity (the estimate reads about 0.97)'),
}


def sections(name: str, seed: int = 1) -> dict[str, dict[str, Any]]:
    """The scenario of case ``name`` with noise and load drawn from ``seed``."""
    case = CASES[name]
    plant = dict(case['plant'])
    ts = plant['sample_time']
    rng = np.random.default_rng(1000 + seed)
    times = np.arange(0.0, DURATION, LOAD_EVERY)
    load = rng.standard_normal(times.size) * case['load']
    load = load + np.where(times >= 300.0, case.get('offset', 0.0), 0.0)
    kp, ti = case['pi']
    return {
        'plant': {'plant': 'fopdt', **plant, 'noise_std': [0.05], 'seed': seed,
                  'real_time_factor': 0.0, **case.get('actuator', {})},
        'controller': {'controller': 'pid', 'sample_time': ts, 'output_names': ['y'],
                       'input_names': ['u'], 'kp': kp, 'ti': ti, 'u_min': -50.0,
                       'u_max': 50.0, 'tuning.gain': plant['gain'],
                       'tuning.time_constant': plant['time_constant'],
                       'tuning.dead_time': plant['dead_time']},
        'reference': {'setpoint.channels': ['y'], 'setpoint.y.times': [0.0, 100.0],
                      'setpoint.y.values': [0.0, case.get('step', 2.0)],
                      'disturbance.channels': ['v'],
                      'disturbance.v.times': [float(t) for t in times],
                      'disturbance.v.values': [round(float(v), 4) for v in load]},
        'harness': {'duration': DURATION, 'clock_mode': 'lockstep', 'title': case['title'],
                    'claim': case['claim']},
    }


def write() -> None:
    from tank_control.core import params_file
    for name in CASES:
        path = REPO / 'config' / 'scenarios' / f'monitor_{name}.yaml'
        params_file.write(sections(name), path)
        text = path.read_text()
        head = (f'# {CASES[name]["title"]}. Written by bench/monitor_cases.py (docs/monitoring.md):\n'
                '# the load on v is a random piecewise-constant sequence (seed 1); y and u are\n'
                '# deviations from the operating point (u in % of valve travel).\n')
        path.write_text(head + text)
        print(path)


def bench(n: int = 50) -> None:
    """Verdicts of ``n`` seeds of the well-tuned case (noise and load drawn anew)."""
    import time
    from collections import Counter

    from tank_control.core import scenario
    from tank_control.harness.performance import trace_performance
    verdicts: Counter[str] = Counter()
    harris = []
    start = time.perf_counter()
    for seed in range(1, n + 1):
        secs = sections('well_tuned', seed)
        trace = scenario.run_in_process(secs)
        body = trace_performance(trace, secs)['y']
        verdicts[body['verdict']] += 1
        harris.append(body['harris_index'])
    h = np.array(harris)
    print(f'{n} seeds of monitor_well_tuned in {time.perf_counter() - start:.1f} s: '
          f'{dict(verdicts)}; false alarms {n - verdicts["good"]} ({100 * (n - verdicts["good"]) / n:.0f} %); '
          f'Harris index median {np.median(h):.3f}, min {h.min():.3f}, max {h.max():.3f}')


def figures() -> None:
    """Each shipped case run in-process, assessed as metrics.json does, plotted as
    ``tank-control assess`` plots; a markdown table of the indices."""
    from tank_control.core import scenario
    from tank_control.harness.performance import plot_assessment, trace_performance
    print('| case | verdict | Harris | oscillation period / amplitude / regularity | '
          'stiction index | saturation % |')
    print('|---|---|---|---|---|---|')
    for name in CASES:
        secs = scenario.sections_of(REPO / 'config' / 'scenarios' / f'monitor_{name}.yaml')
        trace = scenario.run_in_process(secs)
        body = trace_performance(trace, secs)['y']
        step = int(round(secs['controller']['sample_time'] / secs['plant']['sample_time']))
        cols = {'t': trace.t[::step], 'pv': trace['y.y'][::step], 'sp': trace['r.y'][::step],
                'op': trace['u.u'][::step]}
        plot_assessment(cols, body, REPO / 'docs' / 'images' / f'monitor_{name}.png',
                        title=f'monitor_{name}')
        osc = body['oscillation']
        o = (f'{osc["period"]:.1f} s / {osc["amplitude"]:.2f} / {osc["regularity"]:.1f}'
             if osc['detected'] else f'none (regularity {osc["regularity"] or 0:.2f})')
        st = body['stiction']['index']
        print(f'| `monitor_{name}` | {body["verdict"]} | {body["harris_index"]:.2f} | {o} | '
              f'{"–" if st is None else f"{st:.2f}"} | {body["saturation_pct"]:.1f} |')


def main(argv: list[str] | None = None) -> None:
    args = sys.argv[1:] if argv is None else argv
    command = args[0] if args else 'bench'
    if command == 'write':
        write()
    elif command == 'figures':
        figures()
    else:
        bench(int(args[1]) if len(args) > 1 else 50)


if __name__ == '__main__':
    main()
