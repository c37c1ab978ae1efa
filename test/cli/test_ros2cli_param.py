"""`ros2 param` against a node over real DDS: list, get, set, describe, dump, load.

Independent commands run in parallel (``ros2_parallel``) so their discovery waits overlap.
"""
from __future__ import annotations

import json
from pathlib import Path

import yaml
from support.node_host import host_argv
from support.param_node import SPECS
from support.ros2cli import fixture_argv, ros2, ros2_parallel

from tank_control.core import ros_yaml

SPEC = {spec.name: spec for spec in SPECS}


def _start(procs, probe, ros_env, name='fixture', *ros_args):
    proc = procs.start(name, fixture_argv(name, *ros_args), env=ros_env)
    assert probe.wait_for(lambda: name in probe.node.get_node_names(), 60), proc.tail()
    return proc


def test_list_get_set_describe(procs, probe, ros_env):
    _start(procs, probe, ros_env)
    listed, got, hidden_type, described, missing, out_of_range, not_a_choice, read_only = \
        ros2_parallel(
            ros_env,
            ('param', 'list', '/fixture'),
            ('param', 'get', '/fixture', 'gain'),
            ('param', 'get', 'fixture', 'weights', '--hide-type'),
            ('param', 'describe', '/fixture', 'gain', 'period'),
            ('param', 'get', '/fixture', 'no_such_parameter'),
            ('param', 'set', '/fixture', 'gain', '11.5'),
            ('param', 'set', '/fixture', 'mode', 'bogus'),
            ('param', 'set', '/fixture', 'period', '1.0'))

    assert listed.returncode == 0, listed.stderr
    names = [line.strip() for line in listed.stdout.splitlines()]
    assert set(SPEC) <= set(names) and 'use_sim_time' in names
    assert names == sorted(names)

    assert (got.returncode, got.stdout.strip()) == (0, f'Double value is: {SPEC["gain"].default}')
    assert hidden_type.stdout.strip() == str(SPEC['weights'].default)

    assert described.returncode == 0, described.stderr
    text = described.stdout
    assert 'Parameter name: gain\n  Type: double\n' in text
    assert f'Description: {SPEC["gain"].description}' in text
    assert f'Min value: {SPEC["gain"].min}' in text and f'Max value: {SPEC["gain"].max}' in text
    period = text[text.index('Parameter name: period'):]
    assert 'Read only: true' in period and 'Read only' not in text[:text.index('period')]

    assert missing.returncode != 0 and 'no_such_parameter' in missing.stderr

    # Rejections: the node's reason on one stderr line, non-zero exit.
    assert out_of_range.returncode != 0
    assert 'gain' in out_of_range.stderr and '10' in out_of_range.stderr
    assert len(out_of_range.stderr.strip().splitlines()) == 1
    assert not_a_choice.returncode != 0
    assert SPEC['mode'].check('bogus') in not_a_choice.stderr   # the on-set callback's reason
    assert read_only.returncode != 0 and 'read-only' in read_only.stderr.lower()

    # A YAML integer for a double parameter is taken as a double (2 → 2.0); rejected
    # values above never reached the node.
    ok = ros2(ros_env, 'param', 'set', '/fixture', 'gain', '2')
    assert (ok.returncode, ok.stdout.strip()) == (0, 'Set parameter successful'), ok.stderr
    got = ros2(ros_env, 'param', 'get', '/fixture', 'gain')
    assert got.stdout.strip() == 'Double value is: 2.0'


def test_dump_load_and_params_file(procs, probe, ros_env, tmp_path):
    _start(procs, probe, ros_env, 'fixture', '-p', 'gain:=4.25')

    dumped = ros2(ros_env, 'param', 'dump', '/fixture')
    assert dumped.returncode == 0, dumped.stderr
    params = yaml.safe_load(dumped.stdout)['/fixture']['ros__parameters']
    assert params['gain'] == 4.25 and params['filter'] == {'order': SPEC['filter.order'].default}
    assert params['weights'] == SPEC['weights'].default
    assert params['period'] == SPEC['period'].default

    dump_file = tmp_path / 'dump.yaml'
    dump_file.write_text(dumped.stdout)
    bad = tmp_path / 'bad.yaml'
    bad.write_text('/fixture:\n  ros__parameters:\n    count: 500\n')
    other = tmp_path / 'other.yaml'
    other.write_text('/plant:\n  ros__parameters:\n    gain: 1.0\n')
    reloaded, rejected, not_for_us = ros2_parallel(
        ros_env, ('param', 'load', '/fixture', str(dump_file)),
        ('param', 'load', '/fixture', str(bad)), ('param', 'load', '/fixture', str(other)))
    # The dump loads back unchanged (read-only values equal to the node's are skipped).
    assert reloaded.returncode == 0, reloaded.stderr
    assert rejected.returncode != 0 and 'count' in rejected.stderr
    assert not_for_us.returncode != 0 and '/fixture' in not_for_us.stderr

    # A hand-written file: wildcard section, then the node's own section overrides it.
    edited = tmp_path / 'edited.yaml'
    edited.write_text('/**:\n  ros__parameters:\n    gain: 7.0\n    count: 9\n'
                      'fixture:\n  ros__parameters:\n    gain: 3\n    filter:\n      order: 4\n')
    loaded = ros2(ros_env, 'param', 'load', '/fixture', str(edited))
    assert loaded.returncode == 0, loaded.stderr
    params = yaml.safe_load(ros2(ros_env, 'param', 'dump', '/fixture').stdout)
    params = params['/fixture']['ros__parameters']
    assert (params['gain'], params['count'], params['filter']['order']) == (3.0, 9, 4)

    # The dump is a valid --params-file: a restarted node starts with the dumped values.
    procs.stop('fixture')
    restarted = procs.start('restarted', fixture_argv('fixture', '--params-file', str(dump_file)),
                            env=ros_env)
    got = ros2(ros_env, 'param', 'get', '/fixture', 'gain', '--timeout', '20')   # waits for it
    assert got.stdout.strip() == 'Double value is: 4.25', (got.stderr, restarted.tail())


def _round_trip_nodes() -> dict[str, tuple[str, tuple[str, ...]]]:
    """Label (= namespace) → (node module, extra ros args) for every node and kind."""
    from tank_control.core.control.kinds.registry import KINDS as CONTROLLER_KINDS
    from tank_control.core.plants.kinds.registry import KINDS as PLANT_KINDS
    nodes = {f'rt_plant_{kind}': ('plant_node', ('-p', f'plant:={kind}')) for kind in PLANT_KINDS}
    nodes.update({f'rt_controller_{kind}': ('controller_node', ('-p', f'controller:={kind}'))
                  for kind in CONTROLLER_KINDS})
    nodes['rt_reference'] = ('reference_node', ())
    return nodes


#: Channel names that YAML 1.1 or rcl read as booleans or numbers when unquoted.
TRICKY_CHANNELS = {'setpoint.channels': ['y', 'on'], 'disturbance.channels': ['n', 'inf'],
                   'setpoint.on.times': [0.0, 2.0], 'setpoint.on.values': [0.0, 1.0]}


def test_dump_loads_back_unchanged_for_every_node_and_kind(procs, probe, ros_env,
                                                           tmp_path):
    """dump → --params-file of a fresh node (rcl's parser) and `ros2 param load` (ours) →
    dump again: the same text, for the plant of every kind, the controller of every kind
    and the reference (with channel names such as y, on, n, inf). The fresh nodes run in a
    namespace of their own (the file's node key renamed to it), so a stopped node's graph
    entry, which can outlive its process by a DDS lease, is never mistaken for a fresh one.
    The nodes of a phase share one process (support/node_host.py: each node built with its
    own ROS arguments, its --params-file parsed by rcl): 2 processes instead of one a node."""
    nodes = _round_trip_nodes()
    tricky = tmp_path / 'tricky.yaml'
    tricky.write_text(json.dumps({'/**': {'ros__parameters': TRICKY_CHANNELS}}))  # JSON: quoted

    def namespace(label: str, phase: str) -> str:
        return label if phase == 'first' else f'{label}_again'

    def start(phase: str, params_files: dict[str, Path] | None = None) -> None:
        """All nodes of ``phase`` in one process (``params_files`` by label, if given)."""
        hosted = []
        for label, (module, extra) in nodes.items():
            params_file = (params_files or {}).get(label)
            if params_file is None and module == 'reference_node':
                params_file = tricky
            args = ['-r', f'__ns:=/{namespace(label, phase)}', *extra]
            if params_file is not None:
                args += ['--params-file', str(params_file)]
            hosted.append([module, *args])
        procs.start(phase, host_argv(tmp_path / f'{phase}.json', hosted), env=ros_env)

    def running() -> set[str]:
        return {f'{ns.strip("/")}' for _, ns in probe.node.get_node_names_and_namespaces()}

    def full_name(label: str, phase: str = 'first') -> str:
        return f'/{namespace(label, phase)}/{nodes[label][0].removesuffix("_node")}'

    start('first')
    assert probe.wait_for(lambda: set(nodes) <= running(), 90), \
        {n: p.tail() for n, p in procs.processes.items()}
    first = dict(zip(nodes, ros2_parallel(
        ros_env, *[('param', 'dump', full_name(label), '--timeout', '30') for label in nodes],
        timeout=120)))
    for label, dumped in first.items():
        assert dumped.returncode == 0, (label, dumped.stderr)

    # The values a reader needs to be strings are written so that every reader agrees.
    reference = ros_yaml.load(first['rt_reference'].stdout)
    channels = reference['/rt_reference/reference']['ros__parameters']
    assert channels['setpoint']['channels'] == ['y', 'on']
    assert channels['disturbance']['channels'] == ['n', 'inf']
    pid = ros_yaml.load(first['rt_controller_pid'].stdout)['/rt_controller_pid/controller']
    assert pid['ros__parameters']['output_names'] == ['y']

    files = {}
    for label, dumped in first.items():
        key = f'{full_name(label)}:\n'
        assert dumped.stdout.startswith(key), (label, dumped.stdout[:80])
        files[label] = tmp_path / f'{label}.yaml'     # the dump, for the fresh node's name
        files[label].write_text(full_name(label, 'second') + dumped.stdout[len(key) - 2:])
    procs.stop('first')
    start('second', files)
    fresh = {namespace(label, 'second') for label in nodes}
    assert probe.wait_for(lambda: fresh <= running(), 90), procs.processes['second'].tail()
    loaded = dict(zip(nodes, ros2_parallel(
        ros_env, *[('param', 'load', full_name(label, 'second'), str(files[label]),
                    '--timeout', '30') for label in nodes], timeout=120)))
    for label, result in loaded.items():
        assert result.returncode == 0, (label, result.stderr)
    second = dict(zip(nodes, ros2_parallel(
        ros_env, *[('param', 'dump', full_name(label, 'second'), '--timeout', '30')
                   for label in nodes], timeout=120)))
    for label in nodes:
        # on failure: is the node still running, and what did it log (CI once: "Node not
        # found" for a node whose `param load` had just succeeded; not reproduced alone)
        proc = procs.processes['second']
        assert second[label].returncode == 0, (label, second[label].stderr, proc.returncode,
                                               proc.tail(), sorted(running()))
        assert second[label].stdout == files[label].read_text(), label
