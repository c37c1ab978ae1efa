"""ROS 2 parameter files: the one reader and writer (harness, in-process loop, ``ros2 param``).

A file maps node names (``plant``, ``/plant``, ``/**/plant``; ``/**`` or ``/*`` for every node)
to ``ros__parameters``; nested maps are dotted names (``tuning: {rule: mdp}`` is
``tuning.rule``). :func:`read`/:func:`parse` give each section's flat parameters, keyed ``/**``
for the wildcard and by the bare node name otherwise; :func:`node_values` is what one node
receives (wildcard overlaid by its own section); :func:`dumps`/:func:`write` write sections
back nested, in the dialect of :mod:`ros_yaml`. Values must be ROS 2 parameter values: bool,
int, float, string or a non-empty list of one of them, finite numbers.
"""
from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml

from tank_control.core import ros_yaml
from tank_control.core.params import ConfigError

WILDCARD = '/**'
_WILDCARDS = ('/**', '/*')


def read(path: str | Path) -> dict[str, dict[str, Any]]:
    """Sections of the file at ``path`` (see the module docstring); ``ConfigError`` naming the
    file and the entry on bad input."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise ConfigError(f'{path}: cannot read ({exc.strerror})') from None
    return parse(text, str(path))


def yaml_error(where: str, exc: yaml.YAMLError) -> str:
    """One line for a YAML syntax error: ``FILE:LINE:COLUMN: not valid YAML: <problem>
    (<context> at line N)``, lines and columns counted from 1 as editors do."""
    mark = getattr(exc, 'problem_mark', None)
    problem = getattr(exc, 'problem', None)
    if mark is None or not problem:
        return f'{where}: not valid YAML: {str(exc).splitlines()[0]}'
    text = f'{where}:{mark.line + 1}:{mark.column + 1}: not valid YAML: {problem}'
    context, at = getattr(exc, 'context', None), getattr(exc, 'context_mark', None)
    if context and at is not None:
        text += f' ({context} at line {at.line + 1})'
    return text


def parse(text: str, where: str = '<text>') -> dict[str, dict[str, Any]]:
    """Sections of a parameter file's text; ``where`` names it in errors."""
    try:
        document = ros_yaml.load(text)
    except yaml.YAMLError as exc:
        raise ConfigError(yaml_error(where, exc)) from None
    if document is None:
        return {}
    if not isinstance(document, dict):
        raise ConfigError(f'{where}: expected a map of node sections with ros__parameters')
    sections: dict[str, dict[str, Any]] = {}
    for raw, body in document.items():
        name = section_name(str(raw))
        if not isinstance(body, dict) or set(body) != {'ros__parameters'}:
            raise ConfigError(f'{where}: section {raw!r} must hold exactly one key, '
                              'ros__parameters')
        params = body['ros__parameters'] or {}
        if not isinstance(params, dict):
            raise ConfigError(f'{where}: {name}.ros__parameters must be a map')
        flat = ros_yaml.flatten(params)
        sections.setdefault(name, {}).update(
            {key: check_value(f'{where}: {name}.{key}', value) for key, value in flat.items()})
    return sections


def section_name(raw: str) -> str:
    """``/plant``, ``/**/plant`` → ``plant``; the wildcards ``/**``, ``/*`` → ``/**``; other
    patterns (``/ns/*``) and namespaced names (``ns/plant``) are kept."""
    if raw in _WILDCARDS:
        return WILDCARD
    return raw.removeprefix('/**/').lstrip('/')


def node_values(sections: Mapping[str, Mapping[str, Any]], node: str) -> dict[str, Any]:
    """The flat parameters ``node`` receives: the wildcard section overlaid by its own."""
    return {**sections.get(WILDCARD, {}), **sections.get(node, {})}


def values_for(sections: Mapping[str, Mapping[str, Any]], target: str,
               use_wildcards: bool = True) -> dict[str, Any] | None:
    """What the node with the absolute name ``target`` (``/controller``, ``/ns/controller``)
    receives, as rcl matches sections: wildcard patterns (``/**``, ``/ns/*``) first, then its
    own section; None if no section matches."""
    own = target.lstrip('/')
    keys = [k for k in sections if use_wildcards and _matches(k, target)]
    keys += [k for k in sections if '*' not in k and k == own]
    if not keys:
        return None
    out: dict[str, Any] = {}
    for key in keys:
        out.update(sections[key])
    return out


def wildcard_names(sections: Mapping[str, Mapping[str, Any]], target: str) -> set[str]:
    """Names the node ``target`` receives from wildcard sections (``/**``, ``/ns/*``) only."""
    return {name for key in sections if _matches(key, target) for name in sections[key]}


def _matches(key: str, target: str) -> bool:
    return '*' in key and re.fullmatch(_pattern(key), '/' + target.lstrip('/')) is not None


def _pattern(key: str) -> str:
    key = '/' + key.lstrip('/')
    return ''.join('.*' if part == '**' else '[^/]*' if part == '*' else re.escape(part)
                   for part in re.split(r'(\*\*|\*)', key))


def check_value(where: str, value: Any) -> Any:
    """``value`` if it is a ROS 2 parameter value (ints and floats in one list become floats),
    else ``ConfigError`` naming ``where``."""
    if isinstance(value, (bool, int, str)):
        return value
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ConfigError(f'{where}: {value} is not finite; ROS 2 parameter files need '
                              'finite numbers (leave the parameter out for "no limit")')
        return value
    if isinstance(value, list):
        if not value:
            raise ConfigError(f'{where}: empty list (ROS 2 cannot type it); leave it out')
        items = [check_value(where, item) if not isinstance(item, list) else None
                 for item in value]
        kinds = {type(item) for item in items}
        if kinds <= {int, float} and float in kinds:
            return [float(item) for item in items if item is not None]   # homogeneous (none is None)
        if len(kinds) != 1 or None in items:
            raise ConfigError(f'{where}: list mixes types; ROS 2 lists hold one type')
        return items
    raise ConfigError(f'{where}: {value!r} is not a ROS 2 parameter value (bool, int, float, '
                      'string or a list of one of them)')


def nest(flat: Mapping[str, Any]) -> dict[str, Any]:
    """Dotted names → nested maps (the inverse of ``ros_yaml.flatten``): ``{'a.b': 1, 'c': 2}``
    → ``{'a': {'b': 1}, 'c': 2}``; a name that clashes with a value (``a`` and ``a.b``) stays
    dotted."""
    tree: dict[str, Any] = {}
    for name, value in flat.items():
        parts = name.split('.')
        branch: dict[str, Any] = tree
        clash = False                  # a prefix of the name is a value
        for part in parts[:-1]:
            child = branch.setdefault(part, {})
            if not isinstance(child, dict):
                clash = True
                break
            branch = child
        if clash or isinstance(branch.get(parts[-1]), dict):
            tree[name] = value
        else:
            branch[parts[-1]] = value
    return tree


def dumps(sections: Mapping[str, Mapping[str, Any]]) -> str:
    """The text of a parameter file holding ``sections`` (flat values by node name)."""
    return ros_yaml.dump({name: {'ros__parameters': nest(values)}
                          for name, values in sections.items()})


def write(sections: Mapping[str, Mapping[str, Any]], path: str | Path) -> Path:
    """Write ``sections`` as a parameter file at ``path`` (folders created)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(dumps(sections))
    return path


def ros_params_files(argv: Sequence[str]) -> list[str]:
    """The ``--params-file`` paths among the ROS arguments of a command line (between
    ``--ros-args`` and ``--``), in order."""
    files, in_ros_args = [], False
    for i, arg in enumerate(argv):
        if arg == '--ros-args':
            in_ros_args = True
        elif arg == '--':
            in_ros_args = False
        elif in_ros_args and arg == '--params-file' and i + 1 < len(argv):
            files.append(argv[i + 1])
    return files


def node_values_on_command_line(name: str, argv: Sequence[str]) -> dict[str, Any] | None:
    """The parameter values node ``name`` (e.g. ``/controller``) gets from the ``--params-file``
    files in ``argv`` (another node's command line: the plant and the OPC UA bridge read their
    controller's limits this way); None if no file has a section of its own for it, or one
    cannot be read (rcl reports an unreadable file itself)."""
    values: dict[str, Any] = {}
    found = False
    for path in ros_params_files(argv):
        try:
            sections = read(path)
        except ConfigError:
            return None
        own = values_for(sections, name)
        if own is not None and values_for(sections, name, use_wildcards=False):
            found = True
        values.update(own or {})
    return values if found else None
