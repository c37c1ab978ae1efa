"""Message types by name and YAML ⇄ message conversion (rosidl_runtime_py is not installed).

Types are named ``pkg/msg/Type`` (``pkg/Type`` is accepted) and ``pkg/srv/Type``.
Conversion follows the field definitions (``SLOT_TYPES``): nested messages,
sequences and fixed arrays of numbers, strings and messages, ``byte`` fields
as integers, ``builtin_interfaces/Time`` as ``{sec, nanosec}``. As ros2cli's (Humble on):
a ``builtin_interfaces/msg/Time`` field given as ``now`` and a ``std_msgs/msg/Header`` field
given as ``auto`` (its stamp; frame_id empty) hold the wall-clock time of this process, taken
again by ``restamp`` before each message is published.
"""
from __future__ import annotations

import importlib
import time
from collections.abc import Mapping
from typing import Any

import yaml
from rosidl_parser import definition as idl

from tank_control.ros2cli.common import CliError

_FLOAT_TYPES = {'float', 'double', 'long double'}
_INT_RANGES = {f'{sign}int{bits}': ((0, 2 ** bits - 1) if sign else
                                     (-2 ** (bits - 1), 2 ** (bits - 1) - 1))
               for sign in ('', 'u') for bits in (8, 16, 32, 64)}
_INT_RANGES.update({'short': _INT_RANGES['int16'], 'unsigned short': _INT_RANGES['uint16'],
                    'long': _INT_RANGES['int32'], 'unsigned long': _INT_RANGES['uint32'],
                    'long long': _INT_RANGES['int64'],
                    'unsigned long long': _INT_RANGES['uint64'], 'octet': (0, 255)})


def resolve_type(name: str, kind: str = 'msg') -> Any:
    """``sensor_msgs/msg/JointState`` → the class; one-line ``CliError`` if unknown."""
    parts = name.split('/')
    if len(parts) == 2:
        parts = [parts[0], kind, parts[1]]
    if len(parts) != 3 or parts[1] != kind or not all(parts):
        raise CliError(f"The passed {_KIND_WORD[kind]} type is invalid: '{name}' "
                       f'(expected pkg/{kind}/Type)')
    package, _, type_name = parts
    try:
        module = importlib.import_module(f'{package}.{kind}')
        return getattr(module, type_name)
    except (ImportError, AttributeError, ValueError):
        raise CliError(f"The passed {_KIND_WORD[kind]} type is invalid: '{name}' "
                       'is not installed') from None


_KIND_WORD = {'msg': 'message', 'srv': 'service', 'action': 'action'}


def type_name(msg_class: type) -> str:
    """The ``pkg/msg/Type`` name of a message class."""
    package, kind = msg_class.__module__.split('.')[:2]
    return f'{package}/{kind}/{msg_class.__name__}'


def _fields(msg: Any) -> list[tuple[str, Any]]:
    """(field name, rosidl type) pairs in definition order."""
    return list(zip(type(msg).get_fields_and_field_types(), type(msg).SLOT_TYPES))


# message → python ---------------------------------------------------------------------------

def to_python(msg: Any) -> dict[str, Any]:
    """A message as nested plain python (dicts, lists, numbers, strings)."""
    return {name: _value_to_python(getattr(msg, name), slot) for name, slot in _fields(msg)}


def _value_to_python(value: Any, slot: Any) -> Any:
    if isinstance(slot, idl.AbstractNestedType):
        return [_value_to_python(item, slot.value_type) for item in value]
    if isinstance(slot, idl.NamespacedType):
        return to_python(value)
    if isinstance(value, bytes):
        return value[0] if len(value) == 1 else list(value)
    if hasattr(value, 'item'):            # numpy scalars in fixed-size arrays
        return value.item()
    return value


def to_yaml(msg: Any) -> str:
    """Block YAML of a message, as ``ros2 topic echo`` prints it (no trailing separator)."""
    return yaml.safe_dump(to_python(msg), default_flow_style=False, sort_keys=False,
                          allow_unicode=True, width=1000)


# python → message ---------------------------------------------------------------------------

def from_yaml(msg_class: type, text: str | None, stamps: list[Any] | None = None) -> Any:
    """A message of ``msg_class`` with fields set from a YAML dict (empty → defaults);
    ``stamps`` collects the Time messages given as ``now``/``auto`` (``restamp``)."""
    values: Any = {}
    if text is not None and text.strip():
        try:
            values = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            first = str(exc).splitlines()[0]
            raise CliError(f'The passed value is not valid YAML: {first}') from None
    if values is None:
        values = {}
    if not isinstance(values, Mapping):
        raise CliError(f"The passed value needs to be a dictionary in YAML format, got '{text}'")
    msg = msg_class()
    fill(msg, values, stamps=stamps)
    return msg


#: the stamp keywords of ros2cli: (package, type) of the field → the string it takes
STAMP_KEYWORDS = {('builtin_interfaces', 'Time'): 'now', ('std_msgs', 'Header'): 'auto'}


def restamp(stamps: list[Any], now_ns: int | None = None) -> None:
    """Set the Time messages collected by ``from_yaml`` to ``now_ns`` (default: this
    process's wall clock, ``time.time_ns``)."""
    now_ns = time.time_ns() if now_ns is None else now_ns
    for stamp in stamps:
        stamp.sec, stamp.nanosec = divmod(now_ns, 1_000_000_000)


def fill(msg: Any, values: Mapping[str, Any], path: str = '',
         stamps: list[Any] | None = None) -> None:
    """Set the fields of ``msg`` named in ``values`` (recursively); CliError names the field;
    ``stamps`` collects the Time messages given as a stamp keyword."""
    stamps = [] if stamps is None else stamps
    slots = dict(_fields(msg))
    for name, value in values.items():
        where = f'{path}{name}'
        if name not in slots:
            raise CliError(f"Failed to populate field '{where}': {type_name(type(msg))} "
                           f"has no field '{name}' (fields: {', '.join(slots)})")
        try:
            setattr(msg, name, _python_to_value(getattr(msg, name), value, slots[name], where,
                                                stamps))
        except CliError:
            raise
        except (TypeError, ValueError, AssertionError, OverflowError) as exc:
            detail = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise CliError(f"Failed to populate field '{where}': {detail}") from None


def _python_to_value(current: Any, value: Any, slot: Any, where: str,
                     stamps: list[Any]) -> Any:
    if isinstance(slot, idl.AbstractNestedType):
        if not isinstance(value, list):
            raise CliError(f"Failed to populate field '{where}': expected a list, got {value!r}")
        item_slot = slot.value_type
        if isinstance(item_slot, idl.NamespacedType):
            item_class = _class_of(item_slot)
            return [_python_to_value(item_class(), v, item_slot, f'{where}[{i}]', stamps)
                    for i, v in enumerate(value)]
        return [_scalar(v, item_slot, f'{where}[{i}]') for i, v in enumerate(value)]
    if isinstance(slot, idl.NamespacedType):
        keyword = STAMP_KEYWORDS.get((slot.namespaces[0], slot.name))
        if keyword is not None and value == keyword:
            stamp = current if slot.name == 'Time' else current.stamp
            if slot.name == 'Header':
                current.frame_id = ''
            restamp([stamp])
            stamps.append(stamp)
            return current
        if not isinstance(value, Mapping):
            also = f" or '{keyword}' (the current time)" if keyword else ''
            raise CliError(f"Failed to populate field '{where}': expected a dictionary{also}, "
                           f'got {value!r}')
        fill(current, value, where + '.', stamps)
        return current
    return _scalar(value, slot, where)


def _scalar(value: Any, slot: Any, where: str) -> Any:
    """Python value for a basic or string field (ints are accepted for floats)."""
    typename = getattr(slot, 'typename', None)
    if isinstance(slot, (idl.AbstractString, idl.AbstractWString)):
        return value if isinstance(value, str) else str(value)
    number = isinstance(value, (int, float)) and not isinstance(value, bool)
    if typename in _FLOAT_TYPES and number:
        return float(value)
    if typename in _INT_RANGES and number and isinstance(value, int):
        low, high = _INT_RANGES[typename]
        if not low <= value <= high:
            raise CliError(f"Failed to populate field '{where}': {value} is out of the "
                           f'{typename} range [{low}, {high}]')
        return bytes([value]) if typename == 'octet' else value
    if typename == 'boolean' and isinstance(value, bool):
        return value
    if typename in ('char', 'wchar') and isinstance(value, (str, int)):
        return value
    raise CliError(f"Failed to populate field '{where}': {value!r} is not a valid {typename}")


def _class_of(slot: Any) -> type:
    module = importlib.import_module('.'.join(slot.namespaces))
    return getattr(module, slot.name)
