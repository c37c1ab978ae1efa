"""``plot.png``: outputs with their setpoints, inputs and disturbances against time (matplotlib Agg).

One panel per output channel (setpoint dashed), then one panel per unit for
the inputs and for the disturbances. Units: the mixing tank's (003 §1: h in cm,
temperatures in °C, flows in cm³/s); the SISO plants' signals are in the
units of the process, shown as "process units".
"""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402  (the backend is chosen first)

from tank_control.core.trace import Trace  # noqa: E402

UNITS = {'h': 'cm', 'T_out': '°C', 'T_D': '°C', 'T_H': '°C', 'T_C': '°C',
         'F_H': 'cm³/s', 'F_Cin': 'cm³/s', 'F_C': 'cm³/s', 'F_D': 'cm³/s'}
DEFAULT_UNIT = 'process units'


def unit(channel: str) -> str:
    return UNITS.get(channel, DEFAULT_UNIT)


def _panels(trace: Trace) -> list[tuple[str, str, list[str]]]:
    """(kind, unit, channels) per panel: each output alone, inputs and disturbances by unit."""
    panels = [('y', unit(name), [name]) for name in trace.channels('y')]
    for prefix in ('u', 'd'):
        by_unit: dict[str, list[str]] = {}
        for name in trace.channels(prefix):
            by_unit.setdefault(unit(name), []).append(name)
        panels += [(prefix, u, names) for u, names in by_unit.items()]
    return panels


_TITLES = {'y': 'output', 'u': 'manipulated input', 'd': 'disturbance'}


def plot_runs(traces: Sequence[tuple[str, Trace]], path: str | Path, title: str = '') -> Path:
    """Plot one run, or several overlaid (same channels), to a PNG file."""
    path = Path(path)
    first = traces[0][1]
    panels = _panels(first)
    fig, axes = plt.subplots(len(panels), 1, sharex=True, squeeze=False,
                             figsize=(10, 2.2 * len(panels) + 0.8))
    overlay = len(traces) > 1
    for ax, (kind, panel_unit, names) in zip(axes[:, 0], panels):
        for label, trace in traces:
            for name in names:
                column = trace.columns.get(f'{kind}.{name}')
                if column is None:
                    continue
                series = f'{label}: {name}' if overlay else name
                ax.plot(trace.t, column, label=series, drawstyle='steps-post' if kind == 'u' else None)
                if kind == 'y' and f'r.{name}' in trace.columns and (not overlay or trace is first):
                    ax.plot(trace.t, trace.columns[f'r.{name}'], 'k--', linewidth=1,
                            label=f'setpoint {name}', drawstyle='steps-post')
        ax.set_ylabel(f'{_TITLES[kind]} [{panel_unit}]')
        ax.grid(True, alpha=0.3)
        ax.legend(loc='best', fontsize='small')
    axes[-1, 0].set_xlabel('time [s]')
    return save_figure(fig, path, title, dpi=100)


def save_figure(fig, path: Path, title: str = '', dpi: int = 100) -> Path:
    """Give ``fig`` its title, lay it out, write it to ``path`` and close it."""
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path
