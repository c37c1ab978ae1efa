"""What a plant kind is: its configuration (the parameters) and the model it builds."""
from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from tank_control.core.analysis.linear import LinearModel
from tank_control.core.interfaces import Plant
from tank_control.core.params import ParamSpec, config_from, specs_of


@dataclass(frozen=True)
class PlantKind:
    """One plant model as plant_node and the in-process loop see it.

    ``config`` is the model's configuration dataclass (its fields are the parameters);
    ``build`` makes the model from a configuration. Live changes go through the model's
    ``configure(**changes)``. ``tick_reason(config, sample_time)``: relations between the
    model and plant_node's tick ``sample_time`` [s] (a one-line reason or None), e.g. the work
    one tick may cost. ``linear(config)``: the model's linear description for the loop
    analysis (a :class:`~tank_control.core.analysis.linear.LinearModel`, gain magnitude; None
    when these settings have none); ``linear=None``: the kind has none. ``units``: engineering
    unit per channel name (shown by the dashboard; a channel without one is in the model's own
    units).
    """

    name: str
    description: str
    config: type
    build: Callable[[Any], Plant]
    tick_reason: Callable[[Any, float], str | None] | None = None
    linear: Callable[[Any], LinearModel | None] | None = None
    units: Mapping[str, str] = field(default_factory=dict)

    def specs(self) -> tuple[ParamSpec, ...]:
        """The model's parameters."""
        return specs_of(self.config)

    def make(self, values: Mapping[str, Any]) -> Plant:
        """The model from parameter values (missing ones take defaults); ``ConfigError``."""
        return self.build(config_from(self.config, values))
