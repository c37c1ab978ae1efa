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


@pytest.fixture
def lossy_server(rclpy_session):
    """``/lossy/get_parameters`` that loses the response of its first request."""
    import rclpy
    from rcl_interfaces.msg import ParameterValue
    from rcl_interfaces.srv import GetParameters
    from rclpy.executors import SingleThreadedExecutor

    node = rclpy.create_node(f'lossy_{time.monotonic_ns()}', namespace='/lossy',
                             start_parameter_services=False)
    requests: list[list[str]] = []

    def answer(request, response):
        requests.append(list(request.names))
        if len(requests) == 1:
            raise _Lost()
        response.values = [ParameterValue(type=3, double_value=2.5) for _ in request.names]
        return response

    node.create_service(GetParameters, '/lossy/get_parameters', answer)
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
    yield requests
    stop.set()
    thread.join()
    executor.remove_node(node)
    node.destroy_node()
    executor.shutdown()


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
