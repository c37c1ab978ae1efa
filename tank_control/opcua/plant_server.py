"""The simulated plant as an OPC UA server (asyncua), a component plant_node owns.

Address space (namespace ``urn:tank_control:plant``, see docs/opcua.md)::

    Objects/Plant/<output>   Double, read-only   NodeId ns=<i>;s=Plant.<output>
    Objects/Plant/<input>    Double, writable    NodeId ns=<i>;s=Plant.<input>

each with the properties ``EngineeringUnits`` (EUInformation, UNECE code) and ``EURange`` (the
channel's plausible range, ``range.<ch>``). A write of a non-finite value or one outside the
input's EURange is refused with BadOutOfRange (counted in ``refused_writes``).

Interface (any thread; the server runs in its own asyncio thread): :meth:`PlantServer.start`,
:meth:`publish` the outputs of a tick with their SourceTimestamp, :meth:`take_inputs` the
values clients wrote since the last call (latest wins), :meth:`stop`. Works with plant_node in
wall and sim modes; lockstep is refused (:func:`mode_reason`): an OPC UA client answers no
``/clock`` tick, so nothing would pace it.
"""
from __future__ import annotations

import asyncio
import datetime
import math
import threading
from collections.abc import Mapping, Sequence
from typing import Any

from asyncua import Server, ua

from tank_control.core.params import ConfigError
from tank_control.core.ranges import Ranges, default_range
from tank_control.opcua.plant_params import endpoint_param, mode_reason  # noqa: F401 (re-exported)

NAMESPACE = 'urn:tank_control:plant'
#: channel -> (UNECE common code, display name) of its unit (docs/nodes.md "Plausible ranges")
UNITS: Mapping[str, tuple[str, str]] = {
    'h': ('CMT', 'cm'), 'T_out': ('CEL', '°C'), 'T_D': ('CEL', '°C'), 'T_H': ('CEL', '°C'),
    'T_C': ('CEL', '°C'), 'F_H': ('2J', 'cm³/s'), 'F_Cin': ('2J', 'cm³/s'),
    'F_D': ('2J', 'cm³/s')}
_ONE = ('C62', '1')          # a SISO channel: the model's own units
_UNECE_URI = 'http://www.opcfoundation.org/UA/units/un/cefact'


def _nid(name: str, idx: int) -> ua.NodeId:
    """The string NodeId ``ns=<idx>;s=<name>``."""
    return ua.NodeId.from_string(f'ns={idx};s={name}')


def _type(object_id: int) -> ua.NodeId:
    """The NodeId of a standard (ns=0) data type."""
    return ua.NodeId.from_string(f'i={object_id}')


def unece_id(code: str) -> int:
    """The UnitId of a UNECE common code (OPC UA Part 8: its characters packed into an int)."""
    value = 0
    for ch in code.strip():
        value = (value << 8) | ord(ch)
    return value


class PlantServer:
    """The plant's channels served over OPC UA (module doc)."""

    def __init__(self, endpoint: str, outputs: Sequence[str], inputs: Sequence[str],
                 ranges: Ranges | None = None, initial: Mapping[str, float] | None = None,
                 name: str = 'tank_control plant') -> None:
        self.endpoint = endpoint
        self.outputs = tuple(outputs)
        self.inputs = tuple(inputs)
        self.ranges = ranges or Ranges()
        self.initial = dict(initial or {})
        self.name = name
        self.counters = {'writes': 0, 'refused_writes': 0}
        self.namespace_index = 0
        self._lock = threading.Lock()
        self._written: dict[str, float] = {}
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._server: Server | None = None
        self._nodes: dict[str, Any] = {}
        self._pending: dict[str, tuple[float, int]] | None = None
        self._wake: asyncio.Event | None = None
        self._ready = threading.Event()
        self._error: str | None = None

    # ------------------------------------------------------------- interface
    def node_id(self, channel: str) -> str:
        """The NodeId string of ``channel``'s variable."""
        return f'ns={self.namespace_index};s=Plant.{channel}'

    def start(self, timeout: float = 60.0) -> None:
        """Build the address space and listen; ConfigError (one line naming opcua.endpoint)
        when the endpoint cannot be served."""
        self._thread = threading.Thread(target=self._run, name='opcua_plant', daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout):
            raise ConfigError(f'opcua.endpoint: {self.endpoint}: the server did not start '
                              f'within {timeout:g} s')
        if self._error:
            raise ConfigError(f'opcua.endpoint: {self.endpoint}: {self._error}')

    def publish(self, stamp_ns: int, outputs: Mapping[str, float]) -> None:
        """The outputs of a tick, SourceTimestamp ``stamp_ns`` (ns since the epoch, wall
        clock); never blocks (a newer call replaces one not yet written)."""
        loop, wake = self._loop, self._wake
        if loop is None or wake is None:
            return
        with self._lock:
            first = self._pending is None
            self._pending = {ch: (float(v), stamp_ns) for ch, v in outputs.items()
                             if ch in self.outputs}
        if first:
            try:
                loop.call_soon_threadsafe(wake.set)
            except RuntimeError:
                pass

    def take_inputs(self) -> dict[str, float]:
        """The input values clients wrote since the last call (each channel's latest)."""
        with self._lock:
            written, self._written = self._written, {}
        return written

    def stop(self, timeout: float = 10.0) -> None:
        loop = self._loop
        if loop is not None and not loop.is_closed():
            try:
                asyncio.run_coroutine_threadsafe(self._shutdown(), loop).result(timeout)
            except Exception:
                pass
        if self._thread is not None:
            self._thread.join(timeout)

    # -------------------------------------------------------------- the thread
    def _run(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        try:
            loop.run_until_complete(self._main())
        finally:
            loop.close()
            self._ready.set()

    async def _main(self) -> None:
        self._wake = asyncio.Event()
        self._done = asyncio.Event()
        try:
            await self._build()
        except Exception as exc:         # a bad address, a port in use, ...
            self._error = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            self._ready.set()
            return
        self._ready.set()
        while not self._done.is_set():
            await self._wake.wait()
            self._wake.clear()
            with self._lock:
                pending, self._pending = self._pending, None
            if pending and self._server is not None:
                for ch, (value, stamp) in pending.items():
                    when = ua.DateTime.fromtimestamp(stamp / 1e9, datetime.timezone.utc)
                    await self._server.write_attribute_value(self._nodes[ch].nodeid, ua.DataValue(
                        Value=ua.Variant(value, ua.VariantType.Double), SourceTimestamp=when,
                        ServerTimestamp=when))
        server, self._server = self._server, None
        if server is not None:
            await server.stop()

    async def _shutdown(self) -> None:
        self._done.set()
        assert self._wake is not None
        self._wake.set()

    async def _build(self) -> None:
        server = Server()
        await server.init()
        server.set_endpoint(self.endpoint)
        server.set_server_name(self.name)
        idx = await server.register_namespace(NAMESPACE)
        self.namespace_index = idx
        plant = await server.nodes.objects.add_object(_nid('Plant', idx),
                                                      ua.QualifiedName('Plant', idx))
        for ch in (*self.outputs, *self.inputs):
            writable = ch in self.inputs
            value = self.initial.get(ch, 0.0)
            var = await plant.add_variable(_nid(f'Plant.{ch}', idx), ua.QualifiedName(ch, idx),
                                           ua.Variant(float(value), ua.VariantType.Double))
            code, shown = UNITS.get(ch, _ONE)
            # the standard properties (OPC UA Part 8), their browse names in namespace 0
            await var.add_property(
                _nid(f'Plant.{ch}.EngineeringUnits', idx),
                ua.QualifiedName('EngineeringUnits', 0), ua.EUInformation(
                    NamespaceUri=_UNECE_URI, UnitId=unece_id(code),
                    DisplayName=ua.LocalizedText(shown), Description=ua.LocalizedText(shown)),
                datatype=_type(ua.ObjectIds.EUInformation))
            lo, hi = self.ranges.bounds.get(ch) or default_range(ch)
            await var.add_property(_nid(f'Plant.{ch}.EURange', idx),
                                   ua.QualifiedName('EURange', 0), ua.Range(Low=lo, High=hi),
                                   datatype=_type(ua.ObjectIds.Range))
            if writable:
                await var.set_writable()
                server.set_attribute_value_setter(var.nodeid, self._setter(ch, var))
            self._nodes[ch] = var
        await server.start()
        self._server = server

    def _setter(self, channel: str, var: Any) -> Any:
        """A client's write of ``channel``: taken if finite and within the EURange, else
        refused with BadOutOfRange (the variable keeps its value)."""
        def setter(node: Any, attr: Any, value: ua.DataValue) -> None:
            number = value.Value.Value if value.Value is not None else None
            if (not isinstance(number, (int, float)) or isinstance(number, bool)
                    or not math.isfinite(number) or not self.ranges.accepts(channel, number)):
                self.counters['refused_writes'] += 1
                raise ua.uaerrors.BadOutOfRange()
            node.attributes[attr].value = value
            node.attributes[attr].value_callback = None
            with self._lock:
                self._written[channel] = float(number)
            self.counters['writes'] += 1
        return setter
