"""Scenario files: ROS 2 params format in, typed overrides, merged file out."""
from __future__ import annotations

import math
import re

import pytest
import yaml
from support import CONFIG

from tank_control.core import params_file
from tank_control.harness.scenario_file import (
    ScenarioError,
    effective_harness,
    load_scenario,
    parse_override,
    write_params_file,
)

SCENARIO = """
plant:
  ros__parameters:
    plant: ipdt
    gain: 0.05
    dead_time: 5.0
    sample_time: 0.1
controller:
  ros__parameters:
    controller: pid
    kp: 3.14
    tuning:
      rule: none
      dead_time: 5.0
reference:
  ros__parameters:
    setpoint.channels: ['y']
harness:
  ros__parameters:
    duration: 20.0
    clock_mode: lockstep
"""


@pytest.fixture
def scenario_path(tmp_path):
    path = tmp_path / 'ipdt.yaml'
    path.write_text(SCENARIO)
    return path


def test_sections_are_flat_dotted_names_and_harness_typed(scenario_path):
    scenario = load_scenario(scenario_path)
    assert scenario.params('controller')['tuning.rule'] == 'none'
    assert scenario.harness.duration == 20.0
    assert scenario.harness.nodes == ('plant', 'controller', 'reference')
    assert scenario.harness.real_time_factor == 0.0


@pytest.mark.parametrize('text, expected', [
    ('controller.kp=2.5', ('controller', 'kp', 2.5)),
    ('controller.tuning.rule=mdp', ('controller', 'tuning.rule', 'mdp')),
    ('plant.noise_std=1e-3', ('plant', 'noise_std', 0.001)),
    ('reference.values=[0.0, 1, 2]', ('reference', 'values', [0.0, 1, 2])),
    ('harness.nodes=[plant, controller]', ('harness', 'nodes', ['plant', 'controller'])),
    ('plant.enabled=true', ('plant', 'enabled', True)),
])
def test_overrides_are_typed_as_yaml(text, expected):
    assert parse_override(text) == expected


@pytest.mark.parametrize('text, words', [
    ('kp=2', 'NODE.PARAM=VALUE'),
    ('robot.kp=2', 'robot: unknown node; known: controller, harness, plant, reference'),
    ('contoller.kp=2', 'contoller: unknown node; did you mean controller'),
    ('controller.kp', 'NODE.PARAM=VALUE'),
    ('controller.k p=1', 'not a parameter name'),
    ('controller.kp={a: 1}', 'map'),
])
def test_bad_overrides_rejected_with_reason(text, words):
    with pytest.raises(ScenarioError, match=words):
        parse_override(text)


def test_int_override_of_float_parameter_stays_float(scenario_path):
    scenario = load_scenario(scenario_path, ['controller.kp=3', 'controller.tuning.dead_time=6'])
    assert scenario.params('controller')['kp'] == 3.0
    assert isinstance(scenario.params('controller')['kp'], float)
    assert scenario.params('controller')['tuning.dead_time'] == 6.0


@pytest.mark.parametrize('override, words', [
    ('harness.duration=-1', 'harness.duration'),
    ('harness.clock_mode=fast', 'clock_mode'),
    ('harness.nodes=[plant, robot]', 'nodes'),
    ('controller.kp=.inf', 'not finite'),
    ('controller.kp=[1, a]', 'mixes types'),
    ('controller.kp=null', 'not a ROS 2 parameter value'),
])
def test_invalid_values_rejected_naming_the_parameter(scenario_path, override, words):
    with pytest.raises(ScenarioError, match=words):
        load_scenario(scenario_path, [override])


def test_sim_mode_needs_a_positive_real_time_factor(scenario_path):
    scenario = load_scenario(scenario_path)
    with pytest.raises(ScenarioError, match='real_time_factor'):
        effective_harness(scenario, mode='sim')
    assert effective_harness(scenario, mode='sim', rtf=10).harness.real_time_factor == 10.0


@pytest.mark.parametrize('text, words', [
    ('- 1\n- 2\n', 'map of node sections'),
    ('robot:\n  ros__parameters: {a: 1}\n', 'robot: unknown section'),
    ('contoller:\n  ros__parameters: {kp: 1}\n', 'contoller: unknown section; did you mean controller'),
    ('plant:\n  a: 1\n', 'ros__parameters'),
    ('plant: {ros__parameters: {a: [1, [2]]}}', 'mixes types'),
    ('plant: [', 'not valid YAML'),
])
def test_malformed_files_rejected_naming_the_file(tmp_path, text, words):
    path = tmp_path / 'bad.yaml'
    path.write_text(text)
    with pytest.raises(ScenarioError, match=words) as info:
        load_scenario(path)
    assert str(path) in str(info.value)
    assert '\n' not in str(info.value)


@pytest.mark.parametrize('text, where', [
    # libyaml's words, as rcl's parser (also libyaml) gives them to the nodes
    ('plant:\n  ros__parameters:\n    gain: [0.05\n', r":4:1: not valid YAML: did not find "
                                                    r"expected ',' or '\]' "
                                                    r'\(while parsing a flow sequence at line 3\)'),
    ('plant:\n  ros__parameters:\n    plant: ipdt\n   gain: 1\n', r':4:4: not valid YAML: .*'),
    ('plant:\n  ros__parameters:\n    plant: "ipdt\n', r':4:1: not valid YAML: .*quoted scalar at line 3\)'),
])
def test_yaml_syntax_error_names_file_line_and_column(tmp_path, text, where):
    path = tmp_path / 'bad.yaml'
    path.write_text(text)
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    assert re.fullmatch(re.escape(str(path)) + where, str(info.value)), str(info.value)


def test_missing_file_is_a_one_line_error(tmp_path):
    with pytest.raises(ScenarioError, match='cannot read'):
        load_scenario(tmp_path / 'nope.yaml')


def test_merged_file_is_a_standard_params_file_with_the_clock_mode_for_every_node(scenario_path, tmp_path):
    scenario = effective_harness(load_scenario(scenario_path, ['controller.kp=2']), mode='lockstep',
                                 duration=5)
    out = write_params_file(scenario, tmp_path / 'merged.yaml')
    document = yaml.safe_load(out.read_text())
    assert document['controller']['ros__parameters']['kp'] == 2.0
    assert document['controller']['ros__parameters']['tuning'] == {'rule': 'none', 'dead_time': 5.0}
    assert document['plant']['ros__parameters']['clock_mode'] == 'lockstep'
    assert document['controller']['ros__parameters']['clock_mode'] == 'lockstep'
    assert document['reference']['ros__parameters'] == {'clock_mode': 'lockstep',
                                                        'setpoint': {'channels': ['y']}}
    assert document['plant']['ros__parameters']['real_time_factor'] == 0.0
    assert document['harness']['ros__parameters']['duration'] == 5.0
    # The merged file loads back to the same scenario.
    again = load_scenario(out)
    assert again.params('controller') == {**scenario.params('controller'), 'clock_mode': 'lockstep'}
    assert math.isclose(again.harness.duration, 5.0)


@pytest.mark.parametrize('override, reason', [
    ('controller.kpp=2', 'controller.kpp: unknown parameter; did you mean kp?'),
    ('plant.dead_tme=3.0', 'plant.dead_tme: unknown parameter; did you mean dead_time?'),
    ('controller.kp=abc', "controller.kp: 'abc' is a str, expected float"),
    ('controller.sample_time=0.15', 'controller.sample_time: the controller sample time 0.15 s '
                                    'is not a positive integer multiple of the plant sample time '
                                    '0.1 s'),
])
def test_a_value_a_node_would_refuse_is_refused_before_anything_runs(scenario_path, override,
                                                                      reason):
    """The file and --set overrides are checked as the nodes check them, in a ROS run and
    --in-process alike (both load the scenario this way), with the node's reason."""
    with pytest.raises(ScenarioError) as info:
        load_scenario(scenario_path, [override])
    assert reason in str(info.value)


def test_the_in_process_loop_and_the_loop_refuse_a_sample_time_with_the_same_reason():
    from tank_control.core.loop import sample_time_reason
    from tank_control.core.params import ConfigError
    from tank_control.core.scenario import build
    from tank_control.harness.scenario_file import Scenario
    sections = {'plant': {'plant': 'ipdt', 'sample_time': 0.1},
                'controller': {'controller': 'pid', 'kp': 1.0, 'sample_time': 0.15}}
    with pytest.raises(ConfigError) as info:
        build(sections)
    assert str(info.value) == 'controller.' + sample_time_reason(0.1, 0.15)
    assert isinstance(Scenario, type)


@pytest.mark.parametrize('text, reason', [
    ('contoller:\n  ros__parameters: {kp: 1.0}\n', 'contoller: unknown section; did you mean '
                                                   'controller?'),
    ('plant:\n  ros__parameters: {plant: ipdt, dead_tme: 3.0}\n', 'plant.dead_tme: unknown '
                                                                 'parameter; did you mean '
                                                                 'dead_time?'),
    ('/**:\n  ros__parameters: {sample_tme: 0.1}\n', '/**.sample_tme: unknown parameter; did '
                                                      'you mean sample_time?'),
])
def test_misspelt_sections_and_names_in_a_file_are_refused(tmp_path, text, reason):
    path = tmp_path / 'typo.yaml'
    path.write_text(text)
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    assert reason in str(info.value)


@pytest.mark.parametrize('node, name, value, words', [
    ('controller', 'input_names', ['q'], "controller writes input 'q'; plant inputs: ('u',)"),
    ('controller', 'output_names', ['z'], "controller reads output 'z'; plant outputs: ('y',)"),
    ('reference', 'disturbance.channels', ['w'], "disturbance 'w' is not a plant disturbance"),
])
def test_channels_that_do_not_connect_are_refused_before_a_run(tmp_path, node, name, value,
                                                               words):
    """As the in-process loop refuses them, so a ROS run never starts to stall at tick 0."""
    sections = params_file.read(CONFIG / 'ipdt_pid.yaml')
    sections[node][name] = value
    if name == 'disturbance.channels':
        sections[node] = {k: v for k, v in sections[node].items()
                          if not k.startswith('disturbance.v.')}
    path = params_file.write(sections, tmp_path / 'mismatch.yaml')
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    assert str(info.value).startswith(f'{path}: {words}'), str(info.value)
    # a run without the plant's partner nodes (e.g. stand-ins) is not checked
    sections['harness']['nodes'] = ['plant']
    load_scenario(params_file.write(sections, tmp_path / 'plant_only.yaml'))
