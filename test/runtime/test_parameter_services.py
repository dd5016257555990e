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


def _raw_client_endpoints(ctx, srv: str, service: str, client_id: str):
    """A client's request writer and a factory of its reply reader, as rmw_cyclonedds_cpp makes them (the
    ``clientid`` in both endpoints' USER_DATA), so that a test can create the reader late."""
    from cyclonedds.pub import DataWriter
    from cyclonedds.sub import DataReader

    from taiji2_runtime.dds_rclpy.service_client import _qos
    from taiji2_runtime.dds_rclpy.service_types import service_type_hash, wire_class

    participant = ctx.participant()
    request_type, reply_type = wire_class(srv, "Request"), wire_class(srv, "Response")
    user = f"clientid={client_id};"
    writer = DataWriter(participant, ctx.topic(f"rq{service}Request", request_type),
                        _qos(user + f"typehash={service_type_hash(srv, 'Request')};"))

    def reply_reader():
        return DataReader(participant, ctx.topic(f"rr{service}Reply", reply_type),
                          _qos(user + f"typehash={service_type_hash(srv, 'Response')};"))

    return writer, request_type, reply_reader


def test_a_reply_waits_for_a_client_reply_reader_the_server_has_not_matched_yet(context, executor, other_context):
    """A client sees the server before the server sees the client (under load, ``ros2 param`` hung on an embedded
    node): the request arrives, the client's reply reader is not matched yet, and a reply written then is lost.
    The server holds it until the reader is matched; a reply whose client went away is dropped."""
    node = rclpy.node.Node("late_reader", context=context)
    executor.add_node(node)
    node.declare_parameter("gain", 2.5)
    srv, name = "rcl_interfaces/srv/GetParameters", "/late_reader/get_parameters"
    service = next(s for s in node.services if s.service_name == name)

    writer, request_type, reply_reader = _raw_client_endpoints(other_context, srv, name, "1.2.3.4")
    assert spin_until(executor, lambda: writer.get_publication_matched_status().current_count > 0)
    from taiji2_runtime.dds_rclpy.service_types import service_body_class

    service_body = service_body_class(srv, "Request")(names=["gain"])
    writer.write(request_type(client_guid=7, sequence_number=1, body=service_body))
    assert spin_until(executor, lambda: service.held == 1), "the reply was not held for the unmatched reader"

    reader = reply_reader()  # the client's reply reader appears only now
    replies: list = []
    assert spin_until(executor, lambda: replies.extend(reader.take(N=8)) or bool(replies)), "the reply never came"
    assert [(r.client_guid, r.sequence_number, r.body.values[0].double_value) for r in replies] == [(7, 1, 2.5)]
    assert service.held == 0 and service.dropped == 0

    gone, gone_type, _ = _raw_client_endpoints(other_context, srv, name, "5.6.7.8")
    assert spin_until(executor, lambda: gone.get_publication_matched_status().current_count > 0)
    gone.write(gone_type(client_guid=8, sequence_number=1, body=service_body))
    assert spin_until(executor, lambda: service.held == 1)
    gone.__del__()  # the client goes away before its reply reader was ever matched
    assert spin_until(executor, lambda: service.dropped == 1), "the reply of a client that went away was kept"
    assert service.held == 0
