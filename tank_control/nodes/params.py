"""Core ``ParamSpec`` records → declared, validated ROS 2 parameters (one binding per node).

Declares every spec with its ``ParameterDescriptor``, validates start-up values and every
change (spec, then the node's relations between parameters), refuses with a one-line reason
naming the parameter, and hands accepted changes to the node for its next sample. Every
accepted change is published on ``/parameter_audit`` (:data:`AUDIT_TOPIC`). What users see:
docs/nodes.md ("Parameters", "The parameter audit trail"); the rclpy (Jazzy) details:
:class:`ParameterBinding`.
"""
from __future__ import annotations

import json
import math
import sys
import time
from collections.abc import Callable, Iterable, Mapping
from typing import Any

from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                SetParametersResult)
from rclpy.exceptions import ParameterNotDeclaredException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.parameter_service import ParameterService
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String

from tank_control.core import params_file
from tank_control.core.node_specs import declared_anywhere, is_ros_own
from tank_control.core.params import ConfigError, ParamSpec, ParamValue, coerce, unknown_reason

CrossCheck = Callable[[Mapping[str, Any], frozenset[str]], 'str | None']
"""Relations between parameters: (full candidate values, names set in this request or the
params file) → one-line reason or None."""

Derive = Callable[[Mapping[str, Any], frozenset[str]], Mapping[str, Any]]
"""Derived values: (candidate values, names the user set) → extra name → value to set."""

_INT64_MIN, _INT64_MAX = -(2 ** 63), 2 ** 63 - 1

#: Every accepted parameter change of every node: one ``std_msgs/String`` per change holding a
#: JSON object ``{"time", "node", "name", "old", "new", "source"}`` (:func:`audit_record`).
AUDIT_TOPIC = '/parameter_audit'
#: Reliable, transient local, keep-last 100: a reader that joins later (the dashboard) gets the
#: last 100 changes of each node.
AUDIT_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                       reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: ``source`` of a change through the node's ``set_parameters`` service: ``ros2 param set`` /
#: ``load``, the dashboard, the harness — a client the service does not name.
SOURCE_SERVICE = 'set_parameters service'


def audit_value(value: Any) -> Any:
    """A parameter value as JSON holds it: non-finite doubles as ``'inf'``, ``'-inf'``,
    ``'nan'``; arrays as lists."""
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if isinstance(value, (list, tuple)) or hasattr(value, 'tolist'):
        return [audit_value(v) for v in value]
    return value


def audit_record(node: str, name: str, old: Any, new: Any, source: str,
                 when: float | None = None) -> str:
    """The JSON text of one audit message (``time``: wall clock, s since the epoch)."""
    return json.dumps({'time': time.time() if when is None else when, 'node': node,
                       'name': name, 'old': audit_value(old), 'new': audit_value(new),
                       'source': source}, allow_nan=False)


def _wildcard_names(node_name: str, argv: list[str] | None = None) -> set[str]:
    """Names given to ``node_name`` by wildcard sections of the ``--params-file`` files on the
    command line (and not by its own section)."""
    argv = sys.argv if argv is None else argv
    names: set[str] = set()
    for path in params_file.ros_params_files(argv):
        try:
            sections = params_file.read(path)
        except ConfigError:
            continue          # rcl reports an unreadable file itself
        own = params_file.values_for(sections, node_name, use_wildcards=False) or {}
        names |= params_file.wildcard_names(sections, node_name) - set(own)
    return names


def _reason(exc: BaseException) -> str:
    """One line: the exception's text (its type if the text is empty)."""
    text = ' '.join(str(exc).split())
    return text if isinstance(exc, ValueError) and text else f'{type(exc).__name__}: {text}'


class ParameterError(ValueError):
    """A start-up parameter value (params file or default) that the specs reject."""


class UnknownParameter(ParameterNotDeclaredException):
    """A change of a name the node does not declare; the text is the reason with the nearest
    declared name (``'Kp: unknown parameter; did you mean kp?'``). rclpy's parameter services
    answer a ``ParameterNotDeclaredException`` with its text."""

    def __init__(self, reason: str) -> None:
        Exception.__init__(self, reason)


def ros_type(spec: ParamSpec) -> Parameter.Type:
    """The ROS parameter type of a spec: the type of its default.

    List defaults must be non-empty (rclpy cannot type an empty list).
    """
    default = spec.default
    if isinstance(default, list) and not default:
        raise ValueError(f'{spec.name}: a list parameter needs a non-empty default to have a type')
    return Parameter.Type.from_parameter_value(default)


def descriptor(spec: ParamSpec) -> ParameterDescriptor:
    """The ``ParameterDescriptor`` of a spec (description, range, read-only, constraints)."""
    kind = ros_type(spec)
    desc = ParameterDescriptor(
        name=spec.name, description=spec.description, read_only=spec.read_only,
        dynamic_typing=True,
        additional_constraints=f'{_type_word(kind)}; allowed {spec.allowed()}')
    if spec.min is not None or spec.max is not None:
        if kind == Parameter.Type.DOUBLE:
            desc.floating_point_range = [FloatingPointRange(
                from_value=-math.inf if spec.min is None else float(spec.min),
                to_value=math.inf if spec.max is None else float(spec.max), step=0.0)]
        elif kind == Parameter.Type.INTEGER:
            desc.integer_range = [IntegerRange(
                from_value=_INT64_MIN if spec.min is None else int(math.ceil(spec.min)),
                to_value=_INT64_MAX if spec.max is None else int(math.floor(spec.max)), step=0)]
    return desc


def _type_word(kind: Parameter.Type) -> str:
    return kind.name.lower().replace('_', ' ')


class ParameterBinding:
    """The parameters of one node, declared from specs and validated on every change.

    ``cross_check`` sees the complete candidate values (current values with
    the requested changes) and returns a reason or None; ``derive`` returns
    extra values to set along with a change (never overriding a value the user
    set in the same request). Both also run on the start-up values.

    Callbacks (Jazzy): the *pre-set* callback coerces types and adds the derived
    values, so they are set atomically with the change; the *on-set* callback
    validates; the *post-set* callback records accepted changes for
    :meth:`take_pending`. Validation sits in the on-set callback because a pre-set
    callback can only rewrite the list (an emptied list fails with a generic
    message); both run before anything is stored, so a rejected request changes
    nothing. rclpy checks the descriptor's range before any on-set callback, with its
    own wording; so a value the spec refuses is replaced by the pre-set callback with an
    unset value (which passes rclpy's check) and refused by the on-set callback with the
    spec's reason: one wording on every path. Read-only violations are refused by rclpy
    (counted here too). A name the node does not declare is refused in the pre-set
    callback with the nearest declared name (:class:`UnknownParameter`).

    Typing: Jazzy's rclpy does not coerce — a ``double`` parameter rejects an
    integer ("Wrong parameter type"), from a params file and from ``ros2 param set``
    alike, and ``dynamic_typing`` only switches the check off. So each parameter
    keeps the type of its spec's default, integers are converted to doubles here
    (in the overrides before declaring, in the pre-set callback at runtime), and
    parameters are declared with ``dynamic_typing=True`` so a value of a wrong
    type reaches the on-set check and gets a reason naming the parameter instead
    of rclpy's nameless type error.
    """

    def __init__(self, node: Node, specs: Iterable[ParamSpec], *,
                 cross_check: CrossCheck | None = None, derive: Derive | None = None,
                 strict: bool = True) -> None:
        self._node = node
        self._strict = strict
        self._specs = {spec.name: spec for spec in specs}
        self._cross_check = cross_check
        self._derive = derive
        self._values: dict[str, ParamValue] = {}
        self._pending: dict[str, ParamValue] = {}
        self.rejected = 0
        self.last_rejection = ''
        self._writing = False        # inside write(): the node's own values, not a user's
        self._source = ''            # write()'s source while it runs
        self._derived: dict[str, str] = {}   # name -> source, of the request being set
        self._refused: dict[str, str] = {}   # name -> reason, of the request being set
        self.audited = 0
        self._declare()
        self._audit_pub = node.create_publisher(String, AUDIT_TOPIC, AUDIT_QOS)
        node.add_pre_set_parameters_callback(self._pre_set)
        node.add_on_set_parameters_callback(self._on_set)
        node.add_post_set_parameters_callback(self._post_set)

    # ------------------------------------------------------------ start-up
    def _declare(self) -> None:
        overrides = getattr(self._node, '_parameter_overrides', {})   # rclpy has no public getter
        values: dict[str, Any] = {}
        reasons: list[str] = []
        if self._strict:
            reasons += self._unknown_overrides(overrides)
        for name, spec in self._specs.items():
            ros_type(spec)   # fail early on an untypable default
            value = spec.default
            if name in overrides:
                value = coerce(spec, overrides[name].value)
            reason = spec.check(value)
            if reason:
                reasons.append(reason)
            values[name] = value
        if not reasons and self._derive is not None:
            try:
                extra = self._derive(values, frozenset(n for n in self._specs if n in overrides))
            except (ArithmeticError, ValueError) as exc:
                reasons.append(_reason(exc))
            else:
                values.update({k: coerce(self._specs[k], v) for k, v in extra.items()})
        if not reasons and self._cross_check is not None:
            reason = self._checked(values, frozenset(n for n in self._specs if n in overrides))
            if reason:
                reasons.append(reason)
        if reasons:
            raise ParameterError('; '.join(reasons))
        for name, spec in self._specs.items():
            self._node.declare_parameter(name, values[name], descriptor(spec), ignore_override=True)
        self._values = values

    def _unknown_overrides(self, overrides: Mapping[str, Any]) -> list[str]:
        """A start-up value for a name this node does not declare is refused with the nearest
        known name, unless it comes only from a wildcard section (``/**``) of a parameter file
        and another node of the package declares it: such a value is meant for that node and is
        ignored (logged)."""
        shared = _wildcard_names(self._node.get_fully_qualified_name())
        reasons = []
        for name in overrides:
            if name in self._specs or is_ros_own(name):
                continue
            if name in shared and declared_anywhere(name):
                self._node.get_logger().info(f'parameter {name} from a wildcard section ignored: '
                                             "another node's")
            else:
                reasons.append(unknown_reason(name, self._specs))
        return reasons

    # ------------------------------------------------------------ callbacks
    def _pre_set(self, parameters: list[Parameter]) -> list[Parameter]:
        self._derived = {}
        self._refused = {}
        out: list[Parameter] = []
        changes: dict[str, Any] = {}
        for param in parameters:
            spec = self._specs.get(param.name)
            if spec is None and self._strict and not self._node.has_parameter(param.name):
                reason = unknown_reason(param.name, self._specs)
                self._note_rejection(reason)          # counted and logged like any refusal
                raise UnknownParameter(reason)
            if spec is None or param.type_ == Parameter.Type.NOT_SET:
                out.append(param)
                continue
            value = coerce(spec, param.value)
            self._count_descriptor_rejection(spec)
            reason = spec.check(value)
            if reason:
                # refused with the spec's reason by the on-set check: rclpy's range check
                # (from the descriptor, before any on-set callback) must not see the value
                # and answer with its own wording ("Parameter kp out of range Min: ...")
                self._refused[param.name] = reason
                out.append(Parameter(param.name))
                continue
            try:
                param = Parameter(param.name, value=value)
            except (TypeError, ValueError):
                pass   # untypable: the on-set check rejects it with a reason
            out.append(param)
            changes[param.name] = value
        if changes and self._derive is not None:
            candidate = {**self._values, **changes}
            if not any(self._specs[n].check(v) for n, v in changes.items()):
                try:
                    extra = self._derive(candidate, frozenset(changes))
                except (ArithmeticError, ValueError):
                    extra = {}   # the cross-check names the problem
                cause = 'derived from ' + ', '.join(sorted(changes))
                for name, value in extra.items():
                    if name not in changes and value != self._values.get(name):
                        out.append(Parameter(name, value=coerce(self._specs[name], value)))
                        self._derived[name] = cause
        return out

    def _count_descriptor_rejection(self, spec: ParamSpec) -> None:
        """Count (and log) a change rclpy's descriptor check will refuse before our
        on-set check runs (read-only); rclpy returns the reason."""
        if self._writing:
            return               # write() unlocks read-only results for the node itself
        if spec.read_only:
            self._note_rejection(f'{spec.name}: read-only (set at start-up only)')

    def _note_rejection(self, reason: str) -> None:
        self.rejected += 1
        self.last_rejection = reason
        self._node.get_logger().warning(f'parameter change rejected: {reason}')

    def _on_set(self, parameters: list[Parameter]) -> SetParametersResult:
        refused, self._refused = self._refused, {}
        changes: dict[str, Any] = {}
        for param in parameters:
            spec = self._specs.get(param.name)
            if spec is None:
                if self._strict and not self._node.has_parameter(param.name):
                    return self._reject(unknown_reason(param.name, self._specs))
                continue   # not ours (use_sim_time, ...): leave it to its owner
            # rclpy retypes a dynamically typed descriptor to the incoming value's
            # type before this check; keep it at the spec's type (only that is accepted).
            self._node.describe_parameter(param.name).type = ros_type(spec).value
            if param.name in refused:
                return self._reject(refused[param.name])
            value = None if param.type_ == Parameter.Type.NOT_SET else coerce(spec, param.value)
            reason = (f'{param.name}: cannot be unset; allowed {spec.allowed()}' if value is None
                      else spec.check(value))
            if reason:
                return self._reject(reason)
            changes[param.name] = value
        if changes and self._cross_check is not None:
            reason = self._checked({**self._values, **changes}, frozenset(changes))
            if reason:
                return self._reject(reason)
        return SetParametersResult(successful=True)

    def _checked(self, values: Mapping[str, Any], changed: frozenset[str]) -> str | None:
        """The cross-check; a computation it cannot do with these values (an overflow, a
        division by an underflowed product) refuses them with that reason instead of ending
        the node."""
        assert self._cross_check is not None
        try:
            return self._cross_check(values, changed)
        except (ArithmeticError, ValueError) as exc:
            return (f'{", ".join(sorted(changed)) or "parameters"}: refused, the values cannot '
                    f'be used ({_reason(exc)})')

    def _reject(self, reason: str) -> SetParametersResult:
        self._note_rejection(reason)
        return SetParametersResult(successful=False, reason=reason)

    def _post_set(self, parameters: list[Parameter]) -> None:
        derived, self._derived = self._derived, {}
        for param in parameters:
            spec = self._specs.get(param.name)
            if spec is not None:
                value = coerce(spec, param.value)
                old = self._values.get(param.name)
                self._values[param.name] = value
                self._pending[param.name] = value
                if old != value:
                    self._audit(param.name, old, value, derived.get(param.name) or (
                        self._source if self._writing else SOURCE_SERVICE))

    def _audit(self, name: str, old: Any, new: Any, source: str) -> None:
        """One accepted change on ``/parameter_audit`` (and in the log unless the node made
        it itself)."""
        self.audited += 1
        self._audit_pub.publish(String(data=audit_record(
            self._node.get_fully_qualified_name(), name, old, new, source)))
        if not self._writing:
            self._node.get_logger().info(f'parameter {name}: {old!r} -> {new!r} ({source})')

    # ------------------------------------------------------- node's writes
    def write(self, values: Mapping[str, Any], source: str = 'node') -> SetParametersResult:
        """Set parameters from the node itself (results it computed, e.g. tuned gains or
        an identified ``ku``), so ``ros2 param get`` shows them; ``source`` names the cause
        on ``/parameter_audit``.

        The values are validated like any change (atomically), read-only ones
        included — read-only means "not settable by users". They reflect the
        node's state already, so they are not handed back through ``take_pending``.
        """
        params = [Parameter(name, value=coerce(self._specs[name], value))
                  for name, value in values.items()]
        locked = [p.name for p in params if self._node.describe_parameter(p.name).read_only]
        pending_before = dict(self._pending)
        for name in locked:
            self._node.describe_parameter(name).read_only = False
        self._writing, self._source = True, source
        try:
            result = self._node.set_parameters_atomically(params)
        finally:
            self._writing, self._source = False, ''
            for name in locked:
                self._node.describe_parameter(name).read_only = True
        self._pending = pending_before
        return result

    # -------------------------------------------------------------- access
    @property
    def writing(self) -> bool:
        """True while :meth:`write` sets the node's own values (not a user's change)."""
        return self._writing

    @property
    def values(self) -> dict[str, Any]:
        """Current accepted values (a copy), name → value with the spec's type (``Any``: the
        type is the spec's, known at run time)."""
        return dict(self._values)

    def take_pending(self) -> dict[str, Any]:
        """Changes accepted since the last call (applied by the node at its next sample)."""
        pending, self._pending = self._pending, {}
        return pending


class GroupedParameterService(ParameterService):
    """rclpy's parameter services, except that a ``set_parameters`` call carrying several
    parameters is one change: validated and set atomically, all or none.

    rclpy sets the parameters of a ``set_parameters`` request one by one, each validated
    alone, so values that must change together (a schedule's ``times`` and ``values``, as
    ``ros2 param load`` sends them) are refused one at a time, or half applied. Here every
    result of the call carries the one outcome (and its reason). A node uses it instead of
    rclpy's own: ``Node(..., start_parameter_services=False)``, then
    ``GroupedParameterService(node)``.
    """

    def _set_parameters_callback(self, request, response):
        if len(request.parameters) <= 1:
            return super()._set_parameters_callback(request, response)
        node = self._get_node()
        try:
            result = node.set_parameters_atomically(
                [Parameter.from_parameter_msg(p) for p in request.parameters])
        except ParameterNotDeclaredException as exc:
            result = SetParametersResult(successful=False, reason=str(exc))
        response.results = [SetParametersResult(successful=result.successful,
                                                reason=result.reason)
                            for _ in request.parameters]
        return response
