"""plant_node's parameter ``opcua.endpoint`` and its relation to the clock mode, declared
without asyncua (core/node_specs.PlantNode can hold them; the server: plant_server.py)."""
from __future__ import annotations

from typing import Any

from tank_control.core.params import param


def endpoint_param() -> Any:
    """plant_node's ``opcua.endpoint`` (a field of core/node_specs.PlantNode)."""
    return param('', 'serve the plant\'s outputs (read-only) and inputs (writable) as OPC UA '
                 'variables Objects/Plant/<channel> at this address, e.g. '
                 'opc.tcp://0.0.0.0:4840/tank (docs/opcua.md); empty: no server. wall and sim '
                 'only', name='opcua.endpoint', read_only=True)


def mode_reason(clock_mode: str, endpoint: str) -> str | None:
    """Why ``opcua.endpoint`` cannot be used with ``clock_mode`` (None if it can)."""
    if endpoint and clock_mode == 'lockstep':
        return ('opcua.endpoint: set with clock_mode lockstep; an OPC UA client answers no '
                '/clock tick, so nothing would pace the plant: use clock_mode wall or sim, or '
                'an empty opcua.endpoint')
    return None
