"""The OPC UA side of opcua_bridge_node: an asyncua client in its own asyncio thread.

Measurements: one subscription (publishing interval = ``sample_time``, data-change trigger
StatusValueTimestamp, so a value the server re-stamps each scan is reported each scan); each
server sample becomes one :class:`Sample` handed to ``on_sample`` (from the bridge's thread),
stamped with its SourceTimestamp (``stamp: source``; the receive time when absent, counted in
``receive_stamps``). A value whose StatusCode is not Good is never handed on as a number: the
sample is left out (the controller's stale handling applies) and counted in ``bad_status``.

Manipulated values (:meth:`Bridge.write`, any thread): re-checked against the limits
(``range.<ch>``: non-finite or outside refused, counted in ``refused_limits``), held in a
latest-wins slot and written at most once per sample instant (the instant of the controller's
stamp: a value for an instant already written is dropped, counted in ``coalesced_writes``) and
never twice within half a sample time; values that come while the connection is down are
dropped (``dropped_writes``), so a reconnection writes nothing old and never a burst. A
write the server refuses is counted (``refused_writes``) and logged once per channel and
StatusCode.

Connection: connect, check every node (a missing node, one that is no variable, not numeric, or
a manipulated one not writable is a :class:`NodeFault`, one line naming the parameter and the
node id), subscribe, run until the connection is lost; then reconnect after
``reconnect.min_delay`` doubled per failed attempt up to ``reconnect.max_delay``; the
subscription is created anew on each connection. docs/opcua.md.
"""
from __future__ import annotations

import asyncio
import datetime
import math
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from asyncua import Client, ua
from asyncua.common.subscription import Subscription
from asyncua.crypto import security_policies

from tank_control.opcua.config import BridgeSettings

#: ns=0 DataType ids a channel may have (the numeric builtin types) -> their VariantType
NUMERIC_TYPES = {ua.ObjectIds.SByte: ua.VariantType.SByte, ua.ObjectIds.Byte: ua.VariantType.Byte,
                 ua.ObjectIds.Int16: ua.VariantType.Int16, ua.ObjectIds.UInt16: ua.VariantType.UInt16,
                 ua.ObjectIds.Int32: ua.VariantType.Int32, ua.ObjectIds.UInt32: ua.VariantType.UInt32,
                 ua.ObjectIds.Int64: ua.VariantType.Int64, ua.ObjectIds.UInt64: ua.VariantType.UInt64,
                 ua.ObjectIds.Float: ua.VariantType.Float, ua.ObjectIds.Double: ua.VariantType.Double}
_INT_BOUNDS = {ua.VariantType.SByte: (-2 ** 7, 2 ** 7 - 1), ua.VariantType.Byte: (0, 2 ** 8 - 1),
               ua.VariantType.Int16: (-2 ** 15, 2 ** 15 - 1), ua.VariantType.UInt16: (0, 2 ** 16 - 1),
               ua.VariantType.Int32: (-2 ** 31, 2 ** 31 - 1), ua.VariantType.UInt32: (0, 2 ** 32 - 1),
               ua.VariantType.Int64: (-2 ** 63, 2 ** 63 - 1), ua.VariantType.UInt64: (0, 2 ** 64 - 1)}
_EPOCH = datetime.datetime(1970, 1, 1, tzinfo=datetime.timezone.utc)
#: the client's health probe (a read of the server state) period and timeout [s]: a server
#: that stops answering without closing the connection is found within about twice this
WATCHDOG_S = 0.5

Log = Callable[[str, str], None]
"""``log(level, text)``; level 'info', 'warning' or 'error'."""


def _good(dv: ua.DataValue) -> bool:
    return dv.StatusCode is None or dv.StatusCode.is_good()


def _value(dv: ua.DataValue) -> Any:
    """The value of a DataValue read (None if its status is not Good or it has none)."""
    return dv.Value.Value if _good(dv) and dv.Value is not None else None


class NodeFault(Exception):
    """A configured node id the server does not serve as a usable variable (one line)."""


@dataclass(frozen=True)
class Sample:
    """One measurement: ``stamp_ns`` (ns since the epoch, wall clock), channel values."""

    stamp_ns: int
    values: dict[str, float]
    source_stamped: bool


def stamp_ns(dt: datetime.datetime | None, picoseconds: int | None = None) -> int | None:
    """An OPC UA DateTime (UTC) as integer ns since the epoch; None for none."""
    if dt is None:
        return None
    if dt.tzinfo is None:
        dt = dt.replace(tzinfo=datetime.timezone.utc)
    micro = (dt - _EPOCH) // datetime.timedelta(microseconds=1)
    return micro * 1000 + (picoseconds or 0) // 1000


def status_name(code: Any) -> str:
    """The name of a StatusCode (its hex value if unnamed)."""
    try:
        return str(code.name)
    except Exception:
        return f'0x{int(getattr(code, "value", code)):08X}'


def _security_policy(name: str) -> type:
    return {'Basic256Sha256': security_policies.SecurityPolicyBasic256Sha256}[name]


def _certificate_uri(path: str) -> str | None:
    """The URI in the certificate's subjectAltName (the client's application URI must match)."""
    from cryptography import x509
    data = open(path, 'rb').read()
    try:
        cert = x509.load_pem_x509_certificate(data)
    except ValueError:
        cert = x509.load_der_x509_certificate(data)
    try:
        san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    except x509.ExtensionNotFound:
        return None
    uris = san.get_values_for_type(x509.UniformResourceIdentifier)
    return uris[0] if uris else None


class Bridge:
    """asyncua client for one server: measurements in, manipulated values out (module doc).

    ``on_sample(sample)`` and ``log`` are called from the bridge's thread. ``now_ns``: the
    receive clock (ns since the epoch)."""

    def __init__(self, settings: BridgeSettings, on_sample: Callable[[Sample], None],
                 log: Log, now_ns: Callable[[], int] = time.time_ns) -> None:
        self.settings = settings
        self.cfg = settings.node
        self._on_sample = on_sample
        self._log = log
        self._now_ns = now_ns
        self.ts = float(self.cfg.sample_time)
        self.counters = {'samples': 0, 'bad_status': 0, 'receive_stamps': 0, 'writes': 0,
                         'refused_writes': 0, 'refused_limits': 0, 'dropped_writes': 0,
                         'coalesced_writes': 0, 'connections': 0, 'connection_losses': 0}
        self.state = 'connecting'          # connecting | connected | down | node_fault
        self.problem = ''                  # why it is down (one line), '' when connected
        self._logged: set[str] = set()
        self._lock = threading.Lock()
        self._pending: dict[str, float] = {}
        self._pending_instant: int | None = None
        self._written_instant: int | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Event | None = None
        self._write_wake: asyncio.Event | None = None
        self._lost: asyncio.Event | None = None
        self._first = threading.Event()    # the first connection attempt has ended
        self._thread: threading.Thread | None = None
        self._batch: list[tuple[str, Any]] = []
        self._handles: dict[int, str] = {}     # client handle -> measurement channel
        self._latest: dict[str, float] = {}
        self._vtypes: dict[str, ua.VariantType] = {}

    # ------------------------------------------------------------- lifecycle
    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name='opcua_bridge', daemon=True)
        self._thread.start()

    def wait_first_attempt(self, timeout: float) -> bool:
        """True once the first connection attempt has ended (connected, failed or a node
        fault) within ``timeout`` s."""
        return self._first.wait(timeout)

    def stop(self, timeout: float = 5.0) -> None:
        loop, stop = self._loop, self._stop
        if loop is not None and stop is not None and not loop.is_closed():
            try:
                loop.call_soon_threadsafe(stop.set)
            except RuntimeError:
                pass                     # the loop has ended already
        if self._thread is not None:
            self._thread.join(timeout)

    def rearm(self) -> None:
        """Each kind of problem may be logged once again (the node calls it once per
        diagnostics period)."""
        self._logged.clear()

    def _log_once(self, key: str, level: str, text: str) -> None:
        if key not in self._logged:
            self._logged.add(key)
            self._say(level, text)

    def _say(self, level: str, text: str) -> None:
        """The log callback; a failing one never stops the bridge's thread."""
        try:
            self._log(level, text)
        except Exception:
            pass

    # ---------------------------------------------------------------- writes
    def write(self, values: Mapping[str, float], instant: int | None = None) -> list[str]:
        """Offer manipulated values (any thread) of sample ``instant`` (the index of their
        stamp on the loop's grid; None: no instant rule); returns the reasons of values refused
        (non-finite, outside ``range.<ch>``, unknown channel), each counted."""
        refused = []
        accepted = {}
        for ch, value in values.items():
            if ch not in self.settings.manipulated:
                refused.append(f'unknown manipulated channel {ch!r}; known: '
                               + ', '.join(self.settings.manipulated))
                continue
            reason = self.settings.limits.reason(ch, float(value))
            if reason:
                refused.append(reason + ': not written')
                continue
            accepted[ch] = float(value)
        self.counters['refused_limits'] += len(refused)
        if not accepted:
            return refused
        loop, wake = self._loop, self._write_wake
        with self._lock:
            if self.state != 'connected' or loop is None or wake is None:
                self.counters['dropped_writes'] += len(accepted)
                return refused
            if (instant is not None and self._written_instant is not None
                    and instant <= self._written_instant):
                self.counters['coalesced_writes'] += len(accepted)
                return refused        # that sample's values are written already
            self.counters['coalesced_writes'] += sum(1 for ch in accepted if ch in self._pending)
            self._pending.update(accepted)
            if instant is not None:
                self._pending_instant = instant
        try:
            loop.call_soon_threadsafe(wake.set)
        except RuntimeError:
            pass
        return refused

    def forget_instants(self) -> None:
        """The instants of the values written are forgotten (the writer's clock went back:
        its next instant is taken, not dropped as one written already)."""
        with self._lock:
            self._written_instant = self._pending_instant = None

    # ------------------------------------------------------------ the thread
    def _run(self) -> None:
        try:
            asyncio.run(self._main())
        finally:
            self._first.set()

    async def _main(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._stop = asyncio.Event()
        self._write_wake = asyncio.Event()
        delay = self.cfg.reconnect_min
        while not self._stop.is_set():
            client = self._client()
            connections = self.counters['connections']
            try:
                await self._session(client)
            except NodeFault as exc:
                self._set_down('node_fault', str(exc))
                if self._first.is_set():     # at start-up the node exits with it (one line)
                    self._log_once('node_fault', 'error', str(exc) + '; checked again at each '
                                   'reconnection')
            except (OSError, asyncio.TimeoutError, ua.UaError, ConnectionError) as exc:
                self._set_down('down', self._reason(exc))
            except Exception as exc:         # asyncua may raise others on a broken connection
                self._set_down('down', self._reason(exc))
            finally:
                await self._disconnect(client)
            self._first.set()
            if self._stop.is_set():
                break
            if self.counters['connections'] > connections:
                delay = self.cfg.reconnect_min      # it was up: a new loss
            if self.state != 'node_fault':
                self._log_once('down:' + self.problem.split('(')[0], 'error',
                               f'OPC UA {self.cfg.endpoint}: {self.problem}; reconnecting after '
                               f'{delay:g} s, then more rarely (at most every '
                               f'{self.cfg.reconnect_max:g} s)')
            try:
                await asyncio.wait_for(self._stop.wait(), delay)
            except asyncio.TimeoutError:
                pass
            delay = min(delay * 2, self.cfg.reconnect_max)

    def _reason(self, exc: BaseException) -> str:
        if isinstance(exc, ua.UaStatusCodeError):
            return f'refused by the server ({status_name(ua.StatusCode(exc.code))})'
        if isinstance(exc, asyncio.TimeoutError):
            return f'no answer within {self.cfg.request_timeout:g} s'
        text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        return f'not connected ({text[:160]})'

    def _set_down(self, state: str, problem: str) -> None:
        with self._lock:
            was = self.state
            self.state = state
            self.problem = problem
            self._pending.clear()
        if was == 'connected':
            self.counters['connection_losses'] += 1

    def _client(self) -> Client:
        client = Client(self.cfg.endpoint, timeout=self.cfg.request_timeout,
                        watchdog_intervall=WATCHDOG_S)
        client.name = client.description = 'tank_control opcua_bridge'
        if self.cfg.username:
            client.set_user(self.cfg.username)
            client.set_password(self.settings.password or '')
        return client

    async def _disconnect(self, client: Client) -> None:
        try:
            await asyncio.wait_for(client.disconnect(), self.cfg.request_timeout)
        except Exception:
            try:
                client.disconnect_socket()
            except Exception:
                pass

    async def _session(self, client: Client) -> None:
        """One connection: connect, check, subscribe, write until lost (raises) or
        stopped."""
        assert self._stop is not None and self._write_wake is not None
        if self.cfg.policy != 'None':
            uri = _certificate_uri(self.cfg.certificate)
            if uri:
                client.application_uri = uri
            await client.set_security(
                _security_policy(self.cfg.policy), self.cfg.certificate, self.cfg.private_key,
                server_certificate=self.cfg.server_certificate,
                mode=getattr(ua.MessageSecurityMode, self.cfg.mode))
        lost = asyncio.Event()
        self._lost = lost

        async def on_lost(exc: Exception) -> None:
            lost.set()
        client.connection_lost_callback = on_lost
        await asyncio.wait_for(client.connect(auto_reconnect=False), self.cfg.request_timeout * 2)
        nodes = await self._check_nodes(client)
        sub = None
        if self.settings.measurement:
            sub = await self._subscribe(client)
            requests = []
            self._handles = {}
            for i, ch in enumerate(self.settings.measurement):
                handle = 1000 + i
                self._handles[handle] = ch
                requests.append(self._monitor_request(nodes[ch].nodeid, handle))
            results = await sub.create_monitored_items(requests)
            for ch, result in zip(self.settings.measurement, results):
                if isinstance(result, ua.StatusCode):
                    raise NodeFault(f'measurement.{ch}.node_id: '
                                    f'{self.settings.measurement[ch]}: not monitored by the '
                                    f'server ({status_name(result)})')
        with self._lock:
            self._latest.clear()
            self._pending.clear()
            self.state = 'connected'
            self.problem = ''
        self.counters['connections'] += 1
        self._logged.discard('node_fault')
        self._say('info', f'OPC UA {self.cfg.endpoint}: connected ({self.cfg.policy}'
                  + (f', {self.cfg.mode}' if self.cfg.policy != 'None' else '') + '), '
                  f'{len(self.settings.measurement)} measurement and '
                  f'{len(self.settings.manipulated)} manipulated variable(s)')
        self._first.set()
        writer = asyncio.create_task(self._writer(client, nodes))
        stop = asyncio.create_task(self._stop.wait())
        lost_wait = asyncio.create_task(lost.wait())
        try:
            await asyncio.wait([writer, stop, lost_wait], return_when=asyncio.FIRST_COMPLETED)
        finally:
            for task in (writer, stop, lost_wait):
                task.cancel()
            await asyncio.gather(writer, stop, lost_wait, return_exceptions=True)
        if writer.done() and not writer.cancelled() and writer.exception() is not None:
            raise writer.exception()      # type: ignore[misc]
        if not self._stop.is_set():
            raise ConnectionError('connection lost')

    async def _subscribe(self, client: Client) -> Subscription:
        """The subscription (:class:`_Subscription`), created as ``client.create_subscription``
        does."""
        interval = self.cfg.publishing_s() * 1000.0
        params = ua.CreateSubscriptionParameters()
        params.RequestedPublishingInterval = interval
        params.RequestedLifetimeCount = 10000
        params.RequestedMaxKeepAliveCount = client.get_keepalive_count(interval)
        params.MaxNotificationsPerPublish = 10000
        params.PublishingEnabled = True
        params.Priority = 0
        sub = _Subscription(self, client.uaclient.session, params)
        results = await sub.init()
        revised = client.get_subscription_revised_params(params, results)
        if revised:
            await sub.update(revised)
        return sub

    def _monitor_request(self, node_id: ua.NodeId, handle: int) -> ua.MonitoredItemCreateRequest:
        params = ua.MonitoringParameters()
        params.ClientHandle = handle
        params.SamplingInterval = self.cfg.publishing_s() * 1000.0
        params.QueueSize = 4              # every scan of an interval, in order
        params.DiscardOldest = True
        flt = ua.DataChangeFilter()
        flt.Trigger = ua.DataChangeTrigger.StatusValueTimestamp
        params.Filter = flt
        request = ua.MonitoredItemCreateRequest()
        request.ItemToMonitor = ua.ReadValueId(NodeId=node_id, AttributeId=ua.AttributeIds.Value)
        request.MonitoringMode = ua.MonitoringMode.Reporting
        request.RequestedParameters = params
        return request

    async def _check_nodes(self, client: Client) -> dict[str, Any]:
        """Each configured node is a numeric variable (manipulated ones writable): else
        NodeFault naming the parameter and the node id."""
        nodes = {}
        for direction, channels in (('measurement', self.settings.measurement),
                                    ('manipulated', self.settings.manipulated)):
            for ch, text in channels.items():
                where = f'{direction}.{ch}.node_id: {text}'
                node = client.get_node(text)
                attrs = [ua.AttributeIds.NodeClass, ua.AttributeIds.DataType]
                if direction == 'manipulated':
                    attrs.append(ua.AttributeIds.UserAccessLevel)
                read = await node.read_attributes(attrs)
                if not _good(read[0]):
                    raise NodeFault(f'{where}: no such node on {self.cfg.endpoint} '
                                    f'({status_name(read[0].StatusCode)})')
                values = [_value(dv) for dv in read]
                node_class = values[0]
                if node_class != ua.NodeClass.Variable:
                    raise NodeFault(f'{where}: node class {ua.NodeClass(node_class).name}, '
                                    'not a variable')
                data_type = values[1]
                vtype = (NUMERIC_TYPES.get(data_type.Identifier)
                         if data_type is not None and data_type.NamespaceIndex == 0 else None)
                if vtype is None:
                    shown = data_type.to_string() if data_type is not None else 'unknown'
                    try:
                        shown = (await client.get_node(data_type).read_browse_name()).Name
                    except Exception:
                        pass
                    raise NodeFault(f'{where}: data type {shown}, not a number; allowed '
                                    'Double, Float, (U)Int8..64')
                if direction == 'manipulated':
                    level = values[2]
                    if not int(level or 0) & ua.AccessLevel.CurrentWrite.mask:
                        raise NodeFault(f'{where}: not writable for this session (its '
                                        'UserAccessLevel has no CurrentWrite)')
                    self._vtypes[ch] = vtype
                nodes[ch] = node
        return nodes

    # ---------------------------------------------------------- measurements
    def _flush(self) -> None:
        """The data and status changes of one publish response (:class:`_Subscription`, the
        bridge's thread): one sample per distinct SourceTimestamp, in order."""
        batch, self._batch = self._batch, []
        received = self._now_ns()
        changes: list[tuple[int, str, float | None, Any]] = []   # (stamp, channel, value, code)
        for kind, item in batch:
            if kind == 'status':
                code = item.Status
                if not ua.StatusCode(code.value).is_good() and self._lost is not None:
                    self._log_once('substatus', 'warning', 'OPC UA subscription status '
                                   f'{status_name(code)}: reconnecting')
                    self._lost.set()
                continue
            handle, dv = item
            ch = self._handles.get(handle)
            if ch is None or dv is None:
                continue
            stamp = stamp_ns(dv.SourceTimestamp, dv.SourcePicoseconds)
            if stamp is None or self.cfg.stamp == 'receive':
                if self.cfg.stamp == 'source':
                    self.counters['receive_stamps'] += 1
                stamp = received
            code = dv.StatusCode if dv.StatusCode is not None else ua.StatusCode()
            value = None
            if code.is_good() and dv.Value is not None:
                value = self._number(dv.Value.Value)
            changes.append((stamp, ch, value, code))
        if not changes:
            return
        changes.sort(key=lambda c: c[0])
        i = 0
        while i < len(changes):          # one sample per distinct stamp, in order
            stamp = changes[i][0]
            bad = []
            while i < len(changes) and changes[i][0] == stamp:
                _, ch, value, code = changes[i]
                if value is None:
                    bad.append((ch, code))
                    self._latest.pop(ch, None)
                else:
                    self._latest[ch] = value
                i += 1
            if bad:
                self.counters['bad_status'] += 1
                for ch, code in bad:
                    what = (f'status {status_name(code)}' if not code.is_good()
                            else 'a value that is no finite number')   # NaN, inf, text, bool
                    self._log_once(f'bad:{ch}:{what}', 'warning',
                                   f'measurement.{ch}: {what} from '
                                   f'{self.settings.measurement[ch]}: not published (a missing '
                                   'sample)')
                continue
            if len(self._latest) < len(self.settings.measurement):
                continue                 # a channel has no good value yet
            self.counters['samples'] += 1
            try:
                self._on_sample(Sample(stamp, dict(self._latest), self.cfg.stamp == 'source'
                                       and stamp != received))
            except Exception as exc:     # the receiver's fault: said once, the bridge goes on
                self._log_once('on_sample', 'error', f'measurement not handed on: {exc!r}')

    @staticmethod
    def _number(value: Any) -> float | None:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return None
        value = float(value)
        return value if math.isfinite(value) else None

    # ---------------------------------------------------------------- writer
    async def _writer(self, client: Client, nodes: Mapping[str, Any]) -> None:
        """Write the latest offered values (at most one write per half sample time)."""
        assert self._write_wake is not None
        wake = self._write_wake
        wake.clear()
        last = -math.inf
        while True:
            await wake.wait()
            wait = last + self.ts / 2 - time.monotonic()
            if wait > 0:
                await asyncio.sleep(wait)
            wake.clear()
            with self._lock:
                values, self._pending = self._pending, {}
                if values and self._pending_instant is not None:
                    self._written_instant = self._pending_instant
            if not values:
                continue
            last = time.monotonic()
            names = list(values)
            dvs = []
            for ch in names:
                variant = self._variant(ch, values[ch])
                dvs.append(ua.DataValue(Value=variant))
            try:   # no answer within request_timeout: asyncua raises TimeoutError (the client's)
                results = await client.uaclient.write_attributes(
                    [nodes[ch].nodeid for ch in names], dvs, ua.AttributeIds.Value)
            except ua.UaStatusCodeError as exc:   # the whole request refused (a ServiceFault)
                results = [ua.StatusCode(exc.code)] * len(names)
            for ch, result in zip(names, results):
                if result.is_good():
                    self.counters['writes'] += 1
                else:
                    self.counters['refused_writes'] += 1
                    self._log_once(f'write:{ch}:{status_name(result)}', 'warning',
                                   f'manipulated.{ch}: the server refused the write to '
                                   f'{self.settings.manipulated[ch]} ({status_name(result)})')

    def _variant(self, ch: str, value: float) -> ua.Variant:
        vtype = self._vtypes.get(ch, ua.VariantType.Double)
        bounds = _INT_BOUNDS.get(vtype)
        if bounds is None:
            return ua.Variant(float(value), vtype)
        return ua.Variant(int(min(max(round(value), bounds[0]), bounds[1])), vtype)


class _Subscription(Subscription):
    """asyncua's subscription, each publish response handed to the bridge in the publish
    callback itself (:meth:`Bridge._flush`): asyncua's handler path calls a handler from a task
    per notification, after the client has encoded and sent its next PublishRequest (about
    0.2 ms later on a loaded machine; bench/RESULTS.md "OPC UA bridge")."""

    def __init__(self, bridge: Bridge, session: Any, params: ua.CreateSubscriptionParameters
                 ) -> None:
        super().__init__(session, params)    # no handler: publish_callback hands them on
        self._bridge = bridge

    async def publish_callback(self, publish_result: ua.PublishResult) -> None:
        # the bookkeeping of Subscription.publish_callback (asyncua's watchdog, republish)
        self.last_publish_at = time.monotonic()
        message = publish_result.NotificationMessage
        if message.NotificationData is None:
            return
        self.last_sequence_number = int(message.SequenceNumber)
        batch = self._bridge._batch
        for notification in message.NotificationData:
            if isinstance(notification, ua.DataChangeNotification):
                for item in notification.MonitoredItems or ():
                    batch.append(('data', (item.ClientHandle, item.Value)))
            elif isinstance(notification, ua.StatusChangeNotification):
                batch.append(('status', notification))
        self._bridge._flush()
