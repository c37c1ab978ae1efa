"""Open-loop runs of a SISO plant for plant tests."""
from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np


def run(plant, u_of_t: Callable[[float], float], dts: Sequence[float],
        v_of_t: Callable[[float], float] = lambda t: 0.0) -> np.ndarray:
    """Rows (t, y) before the first step and after every step of ``plant`` [s, output unit];
    the input u and disturbance v are held over each step at their value at its start."""
    t, out = 0.0, [(0.0, plant.outputs()[0])]
    for dt in dts:
        plant.step([u_of_t(t)], [v_of_t(t)], dt)
        t += dt
        out.append((t, plant.outputs()[0]))
    return np.array(out)
