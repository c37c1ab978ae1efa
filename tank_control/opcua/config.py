"""opcua_bridge_node's parameters, declared once (``param(...)``), and their checks.

Node-level settings are fields of :class:`BridgeNode`; the channels are lists
``measurement.channels`` / ``manipulated.channels`` with one ``<direction>.<ch>.node_id`` each,
and ``range.<ch>`` for every manipulated channel (the limits a write is re-checked against:
by default the controller's output limits ``u_min``/``u_max`` read from the same
``--params-file``, else the channel's model range). The password is never a parameter: it is
read from the file ``password.file`` or the environment variable ``password.env``.
"""
from __future__ import annotations

import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from tank_control.core import ranges
from tank_control.core.ranges import channel_names
from tank_control.core.node_specs import diagnostics_period_param
from tank_control.core.params import ConfigError, ParamSpec, config_from, param, specs_of

DIRECTIONS = ('measurement', 'manipulated')
POLICIES = ('None', 'Basic256Sha256')
MODES = ('Sign', 'SignAndEncrypt')
_ENDPOINT = re.compile(r'^opc\.tcp://[^/\s:]+(:\d{1,5})?(/\S*)?$')


@dataclass(frozen=True)
class BridgeNode:
    """opcua_bridge_node's own parameters (the channels: :func:`channel_specs`)."""

    endpoint: str = param('', 'the server: opc.tcp://host:port[/path]', read_only=True)
    sample_time: float = param(0.1, 'the loop\'s sample time (the controller\'s): the '
                               'sampling interval the server is asked for, and the grid of the '
                               'manipulated values written: at most one write per sample '
                               'instant of the controller\'s stamps, never two within half a '
                               'sample time', unit='s', min=0.005, max=3600.0, read_only=True)
    publishing_interval: float | None = param(
        None, 'publishing interval of the subscription to the measurements: a server sample '
        'reaches the bridge up to this long after it was taken (each sample is delivered, in '
        'order, up to 4 per interval). 0 = a fifth of sample_time', unit='s', min=0.0,
        max=3600.0, zero=None, tiny=0.001, read_only=True)
    stamp: str = param('source', 'source: measurements stamped with the server\'s '
                       'SourceTimestamp (the bridge\'s receive time for a value without one, '
                       'counted as receive_stamps); receive: always the receive time (a server '
                       'whose clock is not synchronised with this host\'s)',
                       choices=('source', 'receive'), read_only=True)
    policy: str = param('None', 'security policy of the secure channel',
                        choices=POLICIES, name='security.policy', read_only=True)
    mode: str = param('SignAndEncrypt', 'message security mode with a policy other than None',
                      choices=MODES, name='security.mode', read_only=True)
    certificate: str = param('', 'this client\'s certificate (DER or PEM file); needed with a '
                             'policy other than None', name='security.certificate',
                             read_only=True)
    private_key: str = param('', 'this client\'s private key (PEM file, unencrypted)',
                             name='security.private_key', read_only=True)
    server_certificate: str = param('', 'the server\'s certificate (DER or PEM file) trusted '
                                    'for the secure channel; needed with a policy other than '
                                    'None', name='security.server_certificate', read_only=True)
    username: str = param('', 'user name for the session (empty: anonymous); the password comes '
                          'from password.file or password.env, never from a parameter',
                          read_only=True)
    password_file: str = param('', 'file holding the password (its first line)',
                               name='password.file', read_only=True)
    password_env: str = param('', 'name of the environment variable holding the password',
                              name='password.env', read_only=True)
    request_timeout: float = param(2.0, 'longest wait for the server\'s answer to a request '
                                   '(connect, read, write)', unit='s', min=0.1, max=60.0,
                                   read_only=True)
    reconnect_min: float = param(0.5, 'first wait before reconnecting after a loss; doubled '
                                 'after each failed attempt', unit='s', min=0.05, max=60.0,
                                 name='reconnect.min_delay', read_only=True)
    reconnect_max: float = param(10.0, 'longest wait between two reconnection attempts',
                                 unit='s', min=0.05, max=600.0, name='reconnect.max_delay',
                                 read_only=True)
    diagnostics_period: float = diagnostics_period_param()

    def publishing_s(self) -> float:
        """The publishing interval [s] (``publishing_interval``, default sample_time / 5)."""
        return self.publishing_interval or self.sample_time / 5

    def reason(self) -> str | None:
        if not _ENDPOINT.match(self.endpoint):
            return (f'endpoint: {self.endpoint!r} is not an OPC UA TCP address; allowed '
                    'opc.tcp://host:port[/path]')
        if self.reconnect_max < self.reconnect_min:
            return (f'reconnect.max_delay: {self.reconnect_max:g} below reconnect.min_delay '
                    f'{self.reconnect_min:g}')
        if self.policy != 'None':
            for name, value in (('security.certificate', self.certificate),
                                ('security.private_key', self.private_key),
                                ('security.server_certificate', self.server_certificate)):
                if not value:
                    return f'{name}: needed with security.policy {self.policy}; allowed a file'
                if not os.path.isfile(value):
                    return f'{name}: {value!r} is not a readable file'
        if self.password_file and self.password_env:
            return 'password.file and password.env both set; allowed one of them'
        if self.username and not (self.password_file or self.password_env):
            return ('username: set, but neither password.file nor password.env names where the '
                    'password is')
        if (self.password_file or self.password_env) and not self.username:
            return 'password.file/password.env: set without a username'
        return None


@dataclass(frozen=True)
class BridgeSettings:
    """Everything the bridge needs, checked: node-level config, channels, limits, password."""

    node: BridgeNode
    measurement: dict[str, str]            # channel -> node id (in order)
    manipulated: dict[str, str]
    limits: ranges.Ranges = field(default_factory=ranges.Ranges)
    password: str | None = None

    def node_id_param(self, direction: str, channel: str) -> str:
        return f'{direction}.{channel}.node_id'


def channel_specs(values: Mapping[str, Any],
                  actuator: Mapping[str, tuple[float, float]] | None = None
                  ) -> tuple[ParamSpec, ...]:
    """The channel parameters the start-up ``values`` name: the two lists, one node id per
    channel, one ``range.<ch>`` per manipulated channel (defaults ``actuator``: the
    controller's output limits)."""
    specs = []
    for direction in DIRECTIONS:
        names = channel_names(values, direction)
        what = 'read' if direction == 'measurement' else 'written'
        specs.append(ParamSpec(f'{direction}.channels', names or [''],
                               f'{direction} channels (signal names); [\'\'] = none',
                               read_only=True))
        for ch in names:
            specs.append(ParamSpec(f'{direction}.{ch}.node_id', '',
                                   f'NodeId of the variable {ch} is {what} from/to, e.g. '
                                   'ns=2;s=Tank.Level or ns=2;i=1001', read_only=True))
    specs += ranges.range_specs(channel_names(values, 'manipulated'), actuator)
    return tuple(specs)


def specs(values: Mapping[str, Any],
          actuator: Mapping[str, tuple[float, float]] | None = None) -> tuple[ParamSpec, ...]:
    """Every parameter of an opcua_bridge_node started with ``values``."""
    return specs_of(BridgeNode) + channel_specs(values, actuator)


def controller_limits(controller_values: Mapping[str, Any] | None
                      ) -> dict[str, tuple[float, float]]:
    """The controller's output limits ``{channel: (u_min, u_max)}`` (exact, no margin) from its
    parameter values; {} without values or limits."""
    from tank_control.core.node_specs import controller_input_limits
    out = {}
    for ch, (lo, hi) in controller_input_limits(controller_values).items():
        if lo < hi and abs(lo) < float('inf') and abs(hi) < float('inf'):
            out[ch] = (float(lo), float(hi))
    return out


def read_password(node: BridgeNode, environ: Mapping[str, str] | None = None) -> str | None:
    """The password from ``password.file`` (first line) or ``password.env``; None without a
    username. ConfigError naming the parameter when it cannot be read."""
    if not node.username:
        return None
    if node.password_file:
        try:
            with open(node.password_file, encoding='utf-8') as f:
                return f.readline().rstrip('\r\n')
        except OSError as exc:
            raise ConfigError(f'password.file: {node.password_file!r} cannot be read '
                              f'({exc.strerror})') from None
    env = os.environ if environ is None else environ
    if node.password_env not in env:
        raise ConfigError(f'password.env: the environment variable {node.password_env!r} is '
                          'not set')
    return env[node.password_env]


def settings_from(values: Mapping[str, Any],
                  actuator: Mapping[str, tuple[float, float]] | None = None,
                  environ: Mapping[str, str] | None = None) -> BridgeSettings:
    """Checked settings from parameter values; ConfigError naming the parameter."""
    own = {k: v for k, v in values.items() if k in {s.name for s in specs_of(BridgeNode)}}
    node = config_from(BridgeNode, own)
    channels: dict[str, dict[str, str]] = {}
    for direction in DIRECTIONS:
        channels[direction] = {}
        for ch in channel_names(values, direction):
            name = f'{direction}.{ch}.node_id'
            node_id = values.get(name, '')
            if not isinstance(node_id, str) or not node_id.strip():
                raise ConfigError(f'{name}: missing; allowed a NodeId such as ns=2;s=Tank.Level')
            reason = node_id_reason(node_id)
            if reason:
                raise ConfigError(f'{name}: {node_id!r} {reason}')
            channels[direction][ch] = node_id
    if not channels['measurement'] and not channels['manipulated']:
        raise ConfigError('measurement.channels: no channel in measurement.channels nor in '
                          'manipulated.channels; allowed a list of names')
    limits = ranges.ranges_from(values, list(channels['manipulated']), actuator)
    return BridgeSettings(node, channels['measurement'], channels['manipulated'], limits,
                          read_password(node, environ))


def node_id_reason(text: str) -> str | None:
    """None if ``text`` is a NodeId string asyncua can parse, else why not."""
    from asyncua import ua
    try:
        ua.NodeId.from_string(text)
    except Exception as exc:             # asyncua raises several kinds for a bad string
        return (f'is not a NodeId ({str(exc).splitlines()[0][:80]}); allowed e.g. '
                'ns=2;s=Tank.Level, ns=2;i=1001')
    return None
