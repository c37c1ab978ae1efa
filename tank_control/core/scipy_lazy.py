"""scipy routines imported on their first call, not when a module that uses them is imported.

``scipy.optimize`` and ``scipy.signal`` (which pulls in ``scipy.stats``) take about 2 s of CPU
to import on the machines this runs on; every node process imports the controller and plant
tables, but only a tuning or identification step calls these. Importing them lazily keeps a
node's start-up (and every ``tank-control`` or ``ros2`` command) free of that cost. Same
signatures and results as the scipy functions they forward to.
"""
from __future__ import annotations

from typing import Any


def brentq(*args: Any, **kwargs: Any) -> Any:
    """``scipy.optimize.brentq``."""
    from scipy.optimize import brentq as impl
    return impl(*args, **kwargs)


def minimize_scalar(*args: Any, **kwargs: Any) -> Any:
    """``scipy.optimize.minimize_scalar``."""
    from scipy.optimize import minimize_scalar as impl
    return impl(*args, **kwargs)


def least_squares(*args: Any, **kwargs: Any) -> Any:
    """``scipy.optimize.least_squares``."""
    from scipy.optimize import least_squares as impl
    return impl(*args, **kwargs)


def lfilter(*args: Any, **kwargs: Any) -> Any:
    """``scipy.signal.lfilter``."""
    from scipy.signal import lfilter as impl
    return impl(*args, **kwargs)


def expm(*args: Any, **kwargs: Any) -> Any:
    """``scipy.linalg.expm`` (``scipy.linalg`` itself takes ~0.3 s to import)."""
    from scipy.linalg import expm as impl
    return impl(*args, **kwargs)


def solve_discrete_are(*args: Any, **kwargs: Any) -> Any:
    """``scipy.linalg.solve_discrete_are``."""
    from scipy.linalg import solve_discrete_are as impl
    return impl(*args, **kwargs)
