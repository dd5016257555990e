"""Parameter services of embedded nodes, called over DDS from another participant (no ROS 2 needed).

A client in a second context (its own DDS participant, as ``ros2 param`` or ``taiji2 param`` in
another process) lists, reads and sets a node's parameters; a refused set leaves the value as it
was and says why. The rclpy tier runs ``ros2 param`` itself against an embedded node.
"""

from __future__ import annotations

import pytest

from taiji2_runtime.dds_rclpy.parameter_services import to_parameter_value
from taiji2_runtime.dds_rclpy.service_client import ServiceClient
from taiji2_runtime.interfaces import message_class
from taiji2_runtime.ros import rclpy

from support import spin_until

pytestmark = pytest.mark.embedded_runtime(reason=(
    "the embedded runtime's own parameter services and service client; rcl provides them under rclpy "
    "(test/rclpy calls ros2 param on embedded nodes and taiji2 param on rclpy nodes)"
))


@pytest.fixture
def other_context():
    ctx = rclpy.context.Context()
    rclpy.init(args=["client"], context=ctx)
    yield ctx
    rclpy.try_shutdown(context=ctx)


def _call(executor, client: ServiceClient, request):
    assert spin_until(executor, client.service_is_ready), f"{client.service_name} never matched"
    sequence = client.send(request)
    reply: dict[str, object] = {}

    def answered() -> bool:
        if "body" not in reply and (body := client.reply(sequence)) is not None:
            reply["body"] = body
        return "body" in reply

    assert spin_until(executor, answered), f"{client.service_name} did not answer"
    return reply["body"]


def _client(ctx, srv: str, node: str, service: str) -> ServiceClient:
    return ServiceClient(ctx, f"rcl_interfaces/srv/{srv}", f"{node}/{service}")


def test_parameters_are_listed_read_and_set_over_dds(context, executor, other_context):
    node = rclpy.node.Node("tunable", namespace="/lab", context=context)
    executor.add_node(node)
    node.declare_parameter("gain", 2.5)
    node.declare_parameter("filter.order", 4)

    lister = _client(other_context, "ListParameters", "/lab/tunable", "list_parameters")
    listing = _call(executor, lister, lister.request_class())
    assert {"gain", "filter.order", "use_sim_time"} <= set(listing.result.names)
    assert "filter" in listing.result.prefixes

    get = _client(other_context, "GetParameters", "/lab/tunable", "get_parameters")
    values = _call(executor, get, get.request_class(names=["gain", "filter.order", "absent"])).values
    assert [(v.type, v.double_value, v.integer_value) for v in values] == [(3, 2.5, 0), (2, 0.0, 4), (0, 0.0, 0)]

    setter = _client(other_context, "SetParameters", "/lab/tunable", "set_parameters")
    parameter = rclpy.parameter.Parameter("gain", value=4.0)
    msg = message_class("rcl_interfaces/msg/Parameter")
    wrong = message_class("rcl_interfaces/msg/Parameter")(
        name="gain", value=to_parameter_value(rclpy.parameter.Parameter("gain", value="high")))
    results = _call(executor, setter, setter.request_class(
        parameters=[msg(name="gain", value=to_parameter_value(parameter)), wrong])).results
    assert results[0].successful, results[0].reason
    assert not results[1].successful and "gain" in results[1].reason
    assert node.get_parameter("gain").value == 4.0  # the refused string left the accepted value
