"""A tuning rule's costly design (``tuning.rule`` ``ms``: a numerical search) done off the
sampling path of controller_node (wall mode).

A change of the design's inputs (``tuning.*``, the loop's ``sample_time`` and ``n``) while the
rule is a costly one (``core.tuning.rules.COSTLY_RULES``; decided by the rule, not by timing) is
checked on acceptance without the design (ranges, relations: as with ``tuning.rule`` none),
then the design and the full check run in the worker thread of nodes/live_rebuild.py. The
running law keeps sampling with its gains; the first sample after the result is ready writes
the derived gains as parameters ("derived from tuning.…") and takes them with the changed
``tuning.*`` values, bumplessly (as a ``kp`` change). A design that fails leaves the running law
untouched; the node sets the ``tuning.*`` values back and says why. lockstep and sim derive in
the parameter callback, as before (the in-process loop gives the same trace).
"""
from __future__ import annotations

from collections.abc import Mapping
from concurrent.futures import Future
from typing import Any

from tank_control.core.control.kinds.base import ControllerKind
from tank_control.core.params import ConfigError
from tank_control.core.scenario import controller_setup
from tank_control.core.tuning.rules import COSTLY_RULES
from tank_control.nodes.live_rebuild import WorkerJob, _worker

LOOP = ('sample_time', 'n')
"""the loop parameters a model-based rule designs the implemented loop with"""


def design_inputs(names: frozenset[str]) -> frozenset[str]:
    """The names among ``names`` a tuning rule's design reads."""
    return frozenset(n for n in names if n.startswith('tuning.') or n in LOOP)


def costly(values: Mapping[str, Any], changed: frozenset[str]) -> bool:
    """True when ``changed`` needs a new design of a costly rule."""
    return values.get('tuning.rule') in COSTLY_RULES and bool(design_inputs(changed))


def without_design(values: Mapping[str, Any]) -> dict[str, Any]:
    """``values`` checked without the rule's design: the running gains with the new ``tuning.*``
    values (the rule's own relations are checked by the worker)."""
    return {**values, 'tuning.rule': 'none'}


def _design(kind: ControllerKind, kind_names: frozenset[str], values: dict[str, Any],
            given: frozenset[str]) -> dict[str, Any]:
    """The worker's job: the full check (the design included) and the derived values."""
    try:
        controller_setup(values, given=given)
        assert kind.derive is not None
        derived = kind.derive({k: v for k, v in values.items() if k in kind_names})
    except (ConfigError, ArithmeticError, ValueError) as exc:
        raise ValueError(str(exc)) from None
    return {k: v for k, v in derived.items() if k not in given}


class LiveDerive(WorkerJob):
    """One accepted change of the design's inputs being designed in the worker.

    ``changed``: the design inputs changed since the running law was made (held back from the
    running controller until the gains are ready); ``old``: their values then."""

    def __init__(self, kind: ControllerKind, kind_names: frozenset[str],
                 values: Mapping[str, Any], changed: frozenset[str],
                 old: Mapping[str, Any]) -> None:
        self.changed, self.old = changed, dict(old)
        self._future: Future[dict[str, Any]] = _worker().submit(
            _design, kind, kind_names, dict(values), changed)

    def gains(self) -> dict[str, Any]:
        """The derived values; ``ValueError`` with the reason the design failed."""
        return self._future.result()
