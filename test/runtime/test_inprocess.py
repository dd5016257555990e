"""The runtime's rclpy contract, in one process: pub/sub, QoS, parameters, timers on sim time, shutdown."""

from __future__ import annotations

import pytest

from taiji2_runtime.ros import messages, rclpy

from support import spin_until

Node = rclpy.node.Node
QoS = rclpy.qos
Context = rclpy.context.Context


def _wrench(z: float) -> object:
    msg = messages.geometry_msgs.WrenchStamped()
    msg.header.frame_id = "crf"
    msg.wrench.torque.z = z
    return msg


def test_publish_subscribe_delivers_every_message_in_order(context, executor):
    talker, listener = Node("talker", context=context), Node("listener", context=context)
    executor.add_node(talker)
    executor.add_node(listener)
    keep_all = QoS.QoSProfile(history=QoS.HistoryPolicy.KEEP_ALL, reliability=QoS.ReliabilityPolicy.RELIABLE)
    received: list[float] = []
    listener.create_subscription(messages.geometry_msgs.WrenchStamped, "/t",
                                 lambda m: received.append(m.wrench.torque.z), keep_all)
    pub = talker.create_publisher(messages.geometry_msgs.WrenchStamped, "/t", keep_all)
    assert spin_until(executor, lambda: pub.get_subscription_count() == 1)
    n = 2000
    for i in range(n):
        pub.publish(_wrench(float(i)))
    assert spin_until(executor, lambda: len(received) == n)
    assert received == [float(i) for i in range(n)]


def test_publish_refuses_wrong_message_type(context):
    node = Node("typed", context=context)
    pub = node.create_publisher(messages.geometry_msgs.WrenchStamped, "/typed", 10)
    with pytest.raises(TypeError, match="WrenchStamped"):
        pub.publish(messages.std_msgs.Header())


def test_best_effort_writer_does_not_match_reliable_reader(context, executor):
    a, b = Node("a", context=context), Node("b", context=context)
    executor.add_node(a)
    executor.add_node(b)
    reliable = QoS.QoSProfile(depth=10, reliability=QoS.ReliabilityPolicy.RELIABLE)
    b.create_subscription(messages.std_msgs.Header, "/qos", lambda m: None, reliable)
    best_effort_pub = a.create_publisher(messages.std_msgs.Header, "/qos", QoS.qos_profile_sensor_data)
    reliable_pub = a.create_publisher(messages.std_msgs.Header, "/qos", reliable)
    assert spin_until(executor, lambda: reliable_pub.get_subscription_count() == 1)
    executor.spin_once(timeout_sec=0.2)
    assert best_effort_pub.get_subscription_count() == 0  # DDS request/offer: BE cannot serve RELIABLE


def test_remapping_and_namespaces(context):
    ctx = Context()  # a context with its own arguments
    rclpy.init(args=["x", "--ros-args", "-r", "chatter:=/remapped", "-r", "__ns:=/ns1"], context=ctx)
    try:
        node = Node("n", context=ctx)
        assert node.get_namespace() == "/ns1"
        assert node.resolve_topic_name("chatter") == "/remapped"
        assert node.resolve_topic_name("other") == "/ns1/other"
        assert node.resolve_topic_name("~/private") == "/ns1/n/private"
    finally:
        rclpy.try_shutdown(context=ctx)


def _context_with(args: list[str]) -> object:
    ctx = Context()
    rclpy.init(args=["x", "--ros-args", *args], context=ctx)
    return ctx


def test_parameter_overrides_from_command_line_and_params_file(tmp_path):
    params = tmp_path / "p.yaml"
    params.write_text("/**:\n  ros__parameters:\n    gain: 2.5\n    name: file\nother_node:\n"
                      "  ros__parameters:\n    gain: 99.0\n")
    ctx = _context_with(["--params-file", str(params), "-p", "name:=cli", "-p", "n:count:=7",
                         "-p", "vec:=[1e-6, 2.0]"])
    try:
        node = Node("n", context=ctx)
        assert node.declare_parameter("gain", 1.0).value == 2.5       # params file, wildcard node
        assert node.declare_parameter("name", "default").value == "cli"  # -p wins over the file
        assert node.declare_parameter("count", 1).value == 7          # node-specific -p
        assert node.declare_parameter("vec", [0.0, 0.0]).value == [1e-6, 2.0]
        assert node.declare_parameter("untouched", 3.0).value == 3.0
    finally:
        rclpy.try_shutdown(context=ctx)


def test_parameter_type_and_range_are_enforced(context):
    ctx = _context_with(["-p", "rate:=3", "-p", "ratio:=5.0"])
    try:
        node = Node("n", context=ctx)
        with pytest.raises(rclpy.exceptions.InvalidParameterTypeException, match=r"rate.*INTEGER.*DOUBLE"):
            node.declare_parameter("rate", 1.0)
        rcl = messages.rcl_interfaces
        descriptor = rcl.ParameterDescriptor(
            floating_point_range=[rcl.FloatingPointRange(from_value=0.0, to_value=1.0, step=0.0)])
        with pytest.raises(rclpy.exceptions.InvalidParameterValueException, match="ratio"):
            node.declare_parameter("ratio", 0.5, descriptor)
        with pytest.raises(rclpy.exceptions.ParameterNotDeclaredException):
            node.get_parameter("never_declared")
        node.declare_parameter("speed", 1.0)
        result = node.set_parameters([rclpy.parameter.Parameter("speed", value="fast")])[0]
        assert not result.successful and "DOUBLE" in result.reason
        assert node.set_parameters([rclpy.parameter.Parameter("speed", value=2.0)])[0].successful
        assert node.get_parameter("speed").value == 2.0
    finally:
        rclpy.try_shutdown(context=ctx)


def test_malformed_ros_args_raise_clear_errors():
    # rclpy raises rcl's argument errors from its C extension (RCLError, UnknownROSArgsError: both
    # RuntimeErrors), naming the argument
    cases = ((["-p", "novalue"], "novalue"), (["--bogus"], "--bogus"), (["-p"], "-p"))
    for args, pattern in cases:
        ctx = Context()
        with pytest.raises(RuntimeError, match=pattern):
            rclpy.init(args=["x", "--ros-args", *args], context=ctx)
        assert not ctx.ok()


@pytest.mark.embedded_runtime(reason="ROS 2 allows two nodes of one name (rcl only warns); the embedded runtime "
                              "refuses them (docs/runtime.md)")
def test_two_nodes_with_the_same_name_are_refused(context):
    Node("same", context=context)
    with pytest.raises(rclpy.exceptions.NodeNameNonUniqueError, match="/same"):
        Node("same", context=context)


def test_timer_on_simulated_time_follows_clock(context, executor):
    sim_ctx = Context()
    rclpy.init(args=["x", "--ros-args", "-p", "use_sim_time:=true"], context=sim_ctx)
    sim_executor = rclpy.executors.SingleThreadedExecutor(context=sim_ctx)
    try:
        follower = Node("follower", context=sim_ctx)
        sim_executor.add_node(follower)
        ticks: list[int] = []
        follower.create_timer(0.1, lambda: ticks.append(follower.get_clock().now().nanoseconds))
        clock_source = Node("clock_source", context=context)
        executor.add_node(clock_source)
        clock_pub = clock_source.create_publisher(messages.rosgraph_msgs.Clock, "/clock", 10)

        def spin_both() -> None:
            executor.spin_once(timeout_sec=0.01)
            sim_executor.spin_once(timeout_sec=0.01)

        assert spin_until(sim_executor, lambda: clock_pub.get_subscription_count() == 1)
        for k in range(1, 6):  # simulated time 0.1 s ... 0.5 s, far faster than wall time
            clock = messages.rosgraph_msgs.Clock()
            clock.clock.sec, clock.clock.nanosec = divmod(k * 100_000_000, 1_000_000_000)
            clock_pub.publish(clock)
            assert spin_until(sim_executor, lambda k=k: len(ticks) >= k, timeout_s=5.0)
        assert ticks == [k * 100_000_000 for k in range(1, 6)]
        spin_both()
    finally:
        sim_executor.shutdown()
        rclpy.try_shutdown(context=sim_ctx)


def test_spin_until_future_complete_times_out_and_completes(context, executor):
    node = Node("futures", context=context)
    executor.add_node(node)
    future = rclpy.task.Future()
    executor.spin_until_future_complete(future, timeout_sec=0.2)
    assert not future.done()
    node.create_timer(0.05, lambda: future.done() or future.set_result("tick"))
    executor.spin_until_future_complete(future, timeout_sec=5.0)
    assert future.result() == "tick"


def test_shutdown_from_a_callback_ends_spin_with_external_shutdown(context, executor):
    node = Node("stopper", context=context)
    executor.add_node(node)
    node.create_timer(0.05, context.try_shutdown)
    # rclpy's spin() returns once the context is no longer ok between callbacks, and raises
    # ExternalShutdownException when the shutdown comes while it waits: either ends the spin
    try:
        executor.spin()
    except rclpy.executors.ExternalShutdownException:
        pass
    assert not context.ok()
