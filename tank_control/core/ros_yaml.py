"""The YAML dialect of ROS 2 parameter files, for reading and writing them in Python.

ROS 2 reads parameter files with libyaml (YAML 1.1 scalars) plus a few rules of
its own; a file must mean the same to the nodes and to the in-process loop and
the harness, so everything here follows rcl's parser:

* ``1e-3`` is a float (PyYAML's YAML 1.1 resolver would read a string);
* ``y``/``Y``/``n``/``N`` are booleans as values (quote channel names: ``['y']``),
  like YAML 1.1's ``yes``/``no``/``on``/``off``/``true``/``false``;
* ``dump`` quotes every string that either reader (this one or rcl's, which
  also reads ``inf``/``nan`` as numbers) would not read back as that string.
* map keys are names and always strings (a key ``y`` stays ``'y'``).
"""
from __future__ import annotations

import re
from collections.abc import Callable, Mapping
from typing import Any

import yaml


class RosYamlLoader(getattr(yaml, 'CSafeLoader', yaml.SafeLoader)):  # type: ignore[misc]
    """SafeLoader reading scalars and keys the way ROS 2's parameter parser does. Parsed by
    libyaml (PyYAML's C loader: rcl's parser too, and ten times faster than the pure-Python
    one) where PyYAML was built with it; the typing rules below are Python's either way."""


RosYamlLoader.add_implicit_resolver(
    'tag:yaml.org,2002:float',
    re.compile(r'''^[-+]?(?:[0-9][0-9_]*\.[0-9_]*(?:[eE][-+]?[0-9]+)?
                  |[0-9][0-9_]*[eE][-+]?[0-9]+
                  |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
                  |[-+]?\.(?:inf|Inf|INF)
                  |\.(?:nan|NaN|NAN))$''', re.X),
    list('-+0123456789.'))
RosYamlLoader.add_implicit_resolver('tag:yaml.org,2002:bool', re.compile(r'^(?:y|Y|n|N)$'),
                                    list('yYnN'))
RosYamlLoader.bool_values = {**yaml.SafeLoader.bool_values, 'y': True, 'n': False}


def _construct_mapping(loader: yaml.SafeLoader, node: yaml.MappingNode) -> dict[str, Any]:
    """Map keys are parameter/node names, always strings (as in rcl's parser)."""
    out: dict[str, Any] = {}
    for key_node, value_node in node.value:
        key = key_node.value if isinstance(key_node, yaml.ScalarNode) else str(
            loader.construct_object(key_node, deep=True))
        out[key] = loader.construct_object(value_node, deep=True)
    return out


RosYamlLoader.add_constructor('tag:yaml.org,2002:map', _construct_mapping)


class RosYamlDumper(yaml.SafeDumper):
    """Quotes every string that ROS 2 would read as another type (``y``, ``n``,
    ``yes``, ``on``, ``1e-3``, ``inf``, ...), so names survive a round trip through a
    written file."""


def _c_number(text: str) -> bool:
    """True if rcl's ``strtol(text, 0)``/``strtod`` could read ``text`` as a number
    (checked generously: ``inf``, ``nan``, hex floats, octal, ...)."""
    parsers: list[Callable[[str], object]] = [lambda s: int(s, 0), float]
    if '0x' in text.lower():                    # strtod reads hex floats (with the prefix only)
        parsers.append(float.fromhex)
    for parse in parsers:
        try:
            parse(text)
        except ValueError:
            continue
        return True
    return False


def reads_back_as_string(value: str) -> bool:
    """True if ``value`` written as a plain scalar is read back as the same string
    by ``load`` and by rcl's parser (its booleans ``y``, ``yes``, ``on``, ... and
    numbers as strtol/strtod see them)."""
    if not value.strip() or _c_number(value):
        return False
    try:
        plain = load(value)
    except yaml.YAMLError:
        return False
    return isinstance(plain, str) and plain == value


def _represent_str(dumper: yaml.SafeDumper, value: str) -> yaml.Node:
    style = None if reads_back_as_string(value) else "'"
    return dumper.represent_scalar('tag:yaml.org,2002:str', value, style=style)


RosYamlDumper.add_representer(str, _represent_str)


def flatten(tree: Mapping[str, Any], prefix: str = '') -> dict[str, Any]:
    """Nested ``ros__parameters`` maps → dotted parameter names, as rcl reads them."""
    out: dict[str, Any] = {}
    for key, value in tree.items():
        name = f'{prefix}{key}'
        if isinstance(value, dict):
            out.update(flatten(value, name + '.'))
        else:
            out[name] = value
    return out


def load(text: str) -> Any:
    """Parse YAML text as ROS 2 reads parameter files (raises ``yaml.YAMLError``)."""
    return yaml.load(text, Loader=RosYamlLoader)


def dump(document: Any) -> str:
    """YAML text that ROS 2 reads back as ``document``."""
    return yaml.dump(document, Dumper=RosYamlDumper, sort_keys=False, default_flow_style=None,
                     width=100, allow_unicode=True)
