"""plant_node with a user's plant kind that has no live changes (``configure`` is optional,
docs/extending.md): a model parameter set on the running node is refused with its reason, the
node keeps running. The node runs in the test process (a test-only kind registered)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from rclpy.parameter import Parameter

from tank_control.core.params import param
from tank_control.core.plants.kinds import registry
from tank_control.core.plants.kinds.base import PlantKind


@dataclass(frozen=True)
class GainConfig:
    gain: float = param(1.0, 'static gain', unit='1', min=-10.0, max=10.0)


class StaticGain:
    """y = gain·u, without ``configure``: its parameters are fixed once built."""

    output_names, input_names, disturbance_names = ('y',), ('u',), ()
    status: dict = {}

    def __init__(self, config: GainConfig) -> None:
        self.gain, self.y = config.gain, 0.0

    def reset(self) -> None:
        self.y = 0.0

    def outputs(self):
        return np.array([self.y])

    def step(self, u, d, dt):
        self.y = self.gain * float(u[0])


STATIC = PlantKind('static_gain', 'y = gain·u (test)', GainConfig, StaticGain)


def test_a_model_change_on_a_plant_without_configure_is_refused_with_a_reason(probe,
                                                                               monkeypatch):
    from tank_control.nodes.plant_node import PlantNode
    monkeypatch.setitem(registry.KINDS, 'static_gain', STATIC)
    node = PlantNode(parameter_overrides=[Parameter('plant', value='static_gain'),
                                          Parameter('clock_mode', value='sim')])
    probe.executor.add_node(node)
    try:
        result = node.set_parameters([Parameter('gain', value=2.0)])[0]
        assert not result.successful
        assert 'gain' in result.reason and 'restart' in result.reason, result.reason
        assert node.get_parameter('gain').value == 1.0
        # node parameters still change live
        assert node.set_parameters([Parameter('real_time_factor', value=2.0)])[0].successful
        ticks = node.counters['ticks']
        assert probe.wait_for(lambda: node.counters['ticks'] > ticks + 3, 30)
    finally:
        probe.executor.remove_node(node)
        node.destroy_node()
