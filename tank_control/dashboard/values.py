"""Parameter values between the page and the ROS parameter services.

A value typed in the page arrives as text and is read by the parameter's current type (the
``rcl_interfaces/msg/ParameterType`` code of its value): ``true``/``false`` for a bool, a
number for an integer or a double, a JSON list (or comma-separated items) for an array. Text
that does not read as the type is sent as a string all the same, so that the node answers
with its own reason. Non-finite doubles travel to the page as the strings ``inf``, ``-inf``,
``nan`` (JSON has no such numbers).
"""
from __future__ import annotations

import json
import math
from typing import Any

# rcl_interfaces/msg/ParameterType
NOT_SET, BOOL, INTEGER, DOUBLE, STRING = 0, 1, 2, 3, 4
BYTE_ARRAY, BOOL_ARRAY, INTEGER_ARRAY, DOUBLE_ARRAY, STRING_ARRAY = 5, 6, 7, 8, 9
TYPE_NAMES = {NOT_SET: 'not set', BOOL: 'bool', INTEGER: 'integer', DOUBLE: 'double',
              STRING: 'string', BYTE_ARRAY: 'byte array', BOOL_ARRAY: 'bool array',
              INTEGER_ARRAY: 'integer array', DOUBLE_ARRAY: 'double array',
              STRING_ARRAY: 'string array'}
_SCALAR_OF = {BOOL_ARRAY: BOOL, INTEGER_ARRAY: INTEGER, DOUBLE_ARRAY: DOUBLE,
              STRING_ARRAY: STRING, BYTE_ARRAY: INTEGER}


def jsonable(value: Any) -> Any:
    """``value`` with non-finite floats as strings and tuples/arrays as lists (JSON-safe)."""
    if isinstance(value, bool) or value is None or isinstance(value, (int, str)):
        return value
    if isinstance(value, float):
        if math.isnan(value):
            return 'nan'
        if math.isinf(value):
            return 'inf' if value > 0 else '-inf'
        return value
    if isinstance(value, (bytes, bytearray)):
        return list(value)
    if hasattr(value, 'tolist'):
        return jsonable(value.tolist())
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    return str(value)


def _scalar(text: str, kind: int) -> Any:
    text = text.strip()
    if kind == BOOL:
        low = text.lower()
        if low in ('true', '1', 'yes', 'on'):
            return True
        if low in ('false', '0', 'no', 'off'):
            return False
        raise ValueError(text)
    if kind == INTEGER:
        try:
            return int(text)
        except ValueError:
            return float(text)       # the node converts or refuses it with its reason
    if kind == DOUBLE:
        return float(text)
    if text.startswith('"') and text.endswith('"') and len(text) >= 2:
        return json.loads(text)
    return text


def _fits(value: Any) -> bool:
    """``value`` can travel in a ROS parameter message (integers are 64-bit, lists flat)."""
    if isinstance(value, list):
        return all(isinstance(v, (bool, int, float, str)) and _fits(v) for v in value)
    return isinstance(value, bool) or not isinstance(value, int) or -2 ** 63 <= value < 2 ** 63


def parse_text(text: str, kind: int) -> Any:
    """The value that ``text`` (as typed in the page) means for a parameter of type ``kind``;
    text that does not read as that type (also an integer beyond 64 bits, a list item of
    another type) is returned as the string itself."""
    value = _parse(text, kind)
    return value if _fits(value) else text


def _parse(text: str, kind: int) -> Any:
    if kind in _SCALAR_OF:
        stripped = text.strip()
        if stripped.startswith('['):
            try:
                items = json.loads(stripped)
            except ValueError:
                return text
            if not isinstance(items, list):
                return text
            items = [str(item) if not isinstance(item, str) else item for item in items] \
                if kind == STRING_ARRAY else items
        else:
            items = [item for item in (p.strip() for p in stripped.split(',')) if item]
        try:
            return [_scalar(item, _SCALAR_OF[kind]) if isinstance(item, str) else
                    (float(item) if kind == DOUBLE_ARRAY and not isinstance(item, bool)
                     else item)
                    for item in items]
        except (ValueError, TypeError, OverflowError):
            return text
    if kind in (BOOL, INTEGER, DOUBLE):
        try:
            return _scalar(text, kind)
        except ValueError:
            return text
    return text
