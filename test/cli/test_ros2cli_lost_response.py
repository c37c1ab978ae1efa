"""A read whose response is lost is sent again (``nodes/services.py``, through
``ros2cli.common.call_service``).

rmw_fastrtps drops a response when the server has not matched the client's response reader
within 100 ms ("client will not receive response"), which a loaded machine shows while
discovery is still going on: CI saw `ros2 param dump` wait its whole 30 s for one. Here a
server over real DDS loses the first request's response on purpose.
"""
from __future__ import annotations

import threading
import time

import pytest

from tank_control.ros2cli.common import CliError, call_service


class _Lost(Exception):
    """Raised by the server's callback: the request is taken and never answered."""


def _serve(srv_type, name, answer):
    """A node serving ``name`` with ``answer`` until the generator is resumed."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    node = rclpy.create_node(f'lossy_{time.monotonic_ns()}', namespace='/lossy',
                             start_parameter_services=False)
    node.create_service(srv_type, name, answer)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    stop = threading.Event()

    def serve() -> None:
        while not stop.is_set():
            try:
                executor.spin_once(timeout_sec=0.05)
            except _Lost:
                pass

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    yield
    stop.set()
    thread.join()
    executor.remove_node(node)
    node.destroy_node()
    executor.shutdown()


@pytest.fixture
def lossy_server(rclpy_session):
    """``/lossy/get_parameters`` that loses the response of its first request."""
    from rcl_interfaces.msg import ParameterValue
    from rcl_interfaces.srv import GetParameters
    requests: list[list[str]] = []

    def answer(request, response):
        requests.append(list(request.names))
        if len(requests) == 1:
            raise _Lost()
        response.values = [ParameterValue(type=3, double_value=2.5) for _ in request.names]
        return response
    yield from _with_requests(_serve(GetParameters, '/lossy/get_parameters', answer), requests)


@pytest.fixture
def lossy_setter(rclpy_session):
    """``/lossy/set_parameters`` that loses the response of its first request and applies
    each non-empty request (the values it holds are returned with the requests)."""
    from rcl_interfaces.msg import SetParametersResult
    from rcl_interfaces.srv import SetParameters
    requests: list[list[str]] = []
    applied: list[tuple[str, float]] = []

    def answer(request, response):
        requests.append([p.name for p in request.parameters])
        applied.extend((p.name, p.value.double_value) for p in request.parameters)
        if len(requests) == 1:
            raise _Lost()
        response.results = [SetParametersResult(successful=True) for _ in request.parameters]
        return response
    yield from _with_requests(_serve(SetParameters, '/lossy/set_parameters', answer),
                              (requests, applied))


def _with_requests(serving, requests):
    next(serving)
    yield requests
    next(serving, None)


@pytest.fixture
def client(rclpy_session):
    import rclpy
    node = rclpy.create_node(f'client_{time.monotonic_ns()}', start_parameter_services=False)
    yield node
    node.destroy_node()


def test_a_read_is_sent_again_when_its_response_is_lost(lossy_server, client):
    from rcl_interfaces.srv import GetParameters
    request = GetParameters.Request(names=['kp'])
    response = call_service(client, GetParameters, '/lossy/get_parameters', request, 20.0,
                            resend_after=0.5)
    assert [v.double_value for v in response.values] == [2.5]
    assert lossy_server == [['kp'], ['kp']]     # the first lost, the second answered


def test_without_resending_a_lost_response_ends_in_a_clear_error(lossy_server, client):
    from rcl_interfaces.srv import GetParameters
    with pytest.raises(CliError, match="No response from service '/lossy/get_parameters' "
                                       'within 3 s'):
        call_service(client, GetParameters, '/lossy/get_parameters',
                     GetParameters.Request(names=['kp']), 3.0)
    assert lossy_server == [['kp']]


def test_a_set_is_applied_once_and_answered_when_a_response_would_be_lost(lossy_setter, client):
    """`ros2 param set` sends the set once, after an empty set (no effect) was answered.

    CI saw `ros2 param set` wait its whole timeout for a lost response; sending the set
    again could apply it twice, so the client proves the route back first."""
    from rcl_interfaces.msg import Parameter, ParameterValue
    from rcl_interfaces.srv import SetParameters
    requests, applied = lossy_setter
    request = SetParameters.Request(parameters=[
        Parameter(name='kp', value=ParameterValue(type=3, double_value=1.5))])
    response = call_service(client, SetParameters, '/lossy/set_parameters', request, 20.0,
                            prime_with=SetParameters.Request())
    assert [r.successful for r in response.results] == [True]
    assert applied == [('kp', 1.5)]               # applied exactly once
    assert requests[-1] == ['kp'] and all(r == [] for r in requests[:-1])
