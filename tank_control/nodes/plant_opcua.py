"""plant_node's OPC UA server (``opcua.endpoint``, docs/opcua.md): the plant's outputs served
read-only and its inputs writable under Objects/Plant/<channel> (``opcua/plant_server.py``), in
wall and sim mode (lockstep is refused by ``core/node_specs.PlantNode``). Each tick's values are
published with their SourceTimestamp (the stamp in wall mode, the wall clock in sim); inputs a
client wrote are taken at the start of the next step, as a ``manipulated`` message would be."""
from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from typing import Any




class PlantOpcua:
    """The server of one plant node, or nothing when ``endpoint`` is empty."""

    def __init__(self, endpoint: str, outputs: Sequence[str], inputs: Sequence[str],
                 ranges: Any, initial: Mapping[str, float], wall: bool) -> None:
        """Starts the server; ConfigError with the reason when it cannot (e.g. a port in use)."""
        self._outputs, self._wall = tuple(outputs), wall
        self.server: Any = None
        if endpoint:
            from tank_control.opcua.plant_server import PlantServer   # asyncua only when used
            self.server = PlantServer(endpoint, outputs, inputs, ranges, dict(initial))
            self.server.start()

    def measured(self, stamp_ns: int, y: Sequence[float]) -> None:
        if self.server is not None:
            self.server.publish(stamp_ns if self._wall else time.time_ns(),
                                dict(zip(self._outputs, (float(v) for v in y))))

    def take_into(self, protocol: Any) -> None:
        """The values clients wrote since the last call into the plant protocol's held
        inputs, as a ``manipulated`` message's (none without a server)."""
        taken = self.server.take_inputs() if self.server is not None else {}
        if taken:
            protocol.u.update(taken)
            protocol.note_applied(taken)

    def counters(self) -> dict[str, int]:
        """``opcua.*`` for /diagnostics."""
        if self.server is None:
            return {}
        return {f'opcua.{k}': v for k, v in self.server.counters.items()}

    def stop(self) -> None:
        if self.server is not None:
            self.server.stop()



