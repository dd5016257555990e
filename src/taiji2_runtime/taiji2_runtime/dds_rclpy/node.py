"""rclpy.node.Node over Cyclone DDS: publishers, subscriptions, timers, parameters, clock, graph."""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from typing import Any

from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader

from taiji2_runtime.dds_rclpy.arguments import node_matches, parse_ros_args
from taiji2_runtime.dds_rclpy.clock import Clock, ROSClock
from taiji2_runtime.dds_rclpy.clock_type import ClockType
from taiji2_runtime.dds_rclpy.context import Context, forget_deleted_entities, get_default_context
from taiji2_runtime.dds_rclpy.exceptions import NotInitializedException
from taiji2_runtime.dds_rclpy.logging import RcutilsLogger, get_logger
from taiji2_runtime.dds_rclpy.names import expand_topic_name, normalize_namespace, remap_topic_name, validate_node_name
from taiji2_runtime.dds_rclpy.node_parameters import ParameterMixin
from taiji2_runtime.dds_rclpy.parameter import Parameter
from taiji2_runtime.dds_rclpy.publisher import Publisher
from taiji2_runtime.dds_rclpy.qos import QoSProfile, coerce_qos, qos_profile_clock, to_dds_qos
from taiji2_runtime.dds_rclpy.subscription import Subscription
from taiji2_runtime.dds_rclpy.time import Time
from taiji2_runtime.dds_rclpy.timer import Timer
from taiji2_runtime.interfaces import message_class, ros_type_name, type_hash

_NS = 1_000_000_000
_CLOCK_TOPIC = "/clock"


def _dds_topic(fqn: str) -> str:
    return "rt" + fqn


class Node(ParameterMixin):
    """A ROS 2 node: the unit that owns publishers, subscriptions, timers and parameters."""

    def __init__(
        self,
        node_name: str,
        *,
        context: Context | None = None,
        cli_args: Sequence[str] | None = None,
        namespace: str | None = None,
        use_global_arguments: bool = True,
        enable_rosout: bool = True,
        start_parameter_services: bool = True,
        parameter_overrides: Sequence[Parameter] | None = None,
        allow_undeclared_parameters: bool = False,
        automatically_declare_parameters_from_overrides: bool = False,
    ) -> None:
        self._context = context or get_default_context()
        if not self._context.ok():
            raise NotInitializedException("cannot create node")
        local_args = parse_ros_args(["node", "--ros-args", *cli_args]) if cli_args else None
        remaps = list(local_args.remaps) if local_args else []
        overrides = []
        if use_global_arguments:
            remaps += self._context.args.remaps
            overrides += self._context.args.overrides
        if local_args:
            overrides += local_args.overrides
        for rule_node, src, dst in remaps:
            if rule_node in (None, node_name) and src == "__node":
                node_name = dst
            elif rule_node in (None, node_name) and src == "__ns":
                namespace = dst
        validate_node_name(node_name)
        self._name = node_name
        self._namespace = normalize_namespace(namespace)
        self._remaps = remaps
        self._parameter_overrides = {
            o.name: o.value for o in overrides if node_matches(o.node, self._name, self._namespace)
        }
        for p in parameter_overrides or []:
            self._parameter_overrides[p.name] = p.value
        self._logger = get_logger(self._name if self._namespace == "/" else
                                  f"{self._namespace.strip('/').replace('/', '.')}.{self._name}")
        self._publishers: list[Publisher] = []
        self._subscriptions: list[Subscription] = []
        self._timers: list[Timer] = []
        self._clock = ROSClock()
        self._clock_subscription: Subscription | None = None
        self.executor: Any = None
        self._services: list[Any] = []
        self._rosout: Publisher | None = None
        self._context.register_node(self)
        self._init_parameters(allow_undeclared_parameters)
        self.add_on_set_parameters_callback(self._on_use_sim_time)
        self.declare_parameter("use_sim_time", False)
        if automatically_declare_parameters_from_overrides:
            for name, value in self._parameter_overrides.items():
                if not self.has_parameter(name):
                    self.declare_parameter(name, value)
        if start_parameter_services:
            from taiji2_runtime.dds_rclpy.parameter_services import start_parameter_services as start

            self._services = start(self)
        if enable_rosout:
            from taiji2_runtime.dds_rclpy import rosout

            self._rosout = self._make_publisher(message_class("rcl_interfaces/msg/Log"), rosout.ROSOUT_TOPIC,
                                                rosout.qos_profile_rosout_default)
            rosout.attach(self._logger.name, self._rosout)
        self._context.entities_changed()

    # -- identity ------------------------------------------------------------------------------
    @property
    def context(self) -> Context:
        return self._context

    def get_name(self) -> str:
        return self._name

    def get_namespace(self) -> str:
        return self._namespace

    def get_fully_qualified_name(self) -> str:
        return f"{self._namespace.rstrip('/')}/{self._name}"

    def get_logger(self) -> RcutilsLogger:
        return self._logger

    def get_clock(self) -> Clock:
        return self._clock

    @property
    def publishers(self) -> Iterator[Publisher]:
        yield from self._publishers

    @property
    def subscriptions(self) -> Iterator[Subscription]:
        yield from self._subscriptions

    @property
    def services(self) -> Iterator[Any]:
        yield from self._services

    @property
    def timers(self) -> Iterator[Timer]:
        yield from self._timers

    def resolve_topic_name(self, topic: str, *, only_expand: bool = False) -> str:
        fqn = expand_topic_name(topic, self._name, self._namespace)
        return fqn if only_expand else remap_topic_name(fqn, self._remaps, self._name, self._namespace)

    # -- simulated time ------------------------------------------------------------------------
    def _on_use_sim_time(self, parameters: list[Parameter]) -> Any:
        result = message_class("rcl_interfaces/msg/SetParametersResult")()
        result.successful = True
        for p in parameters:
            if p.name != "use_sim_time":
                continue
            if not isinstance(p.value, bool):
                result.successful, result.reason = False, "use_sim_time must be a bool"
                return result
            self._enable_sim_time(p.value)
        return result

    def _enable_sim_time(self, enabled: bool) -> None:
        self._clock._set_ros_time_is_active(enabled)
        if enabled and self._clock_subscription is None:
            clock_type = message_class("rosgraph_msgs/msg/Clock")
            self._clock_subscription = self.create_subscription(
                clock_type, _CLOCK_TOPIC, self._on_clock, qos_profile_clock
            )
        elif not enabled and self._clock_subscription is not None:
            self.destroy_subscription(self._clock_subscription)
            self._clock_subscription = None

    def _on_clock(self, msg: Any) -> None:
        self._clock.set_ros_time_override(Time.from_msg(msg.clock))

    # -- entities ------------------------------------------------------------------------------
    def create_publisher(
        self, msg_type: type, topic: str, qos_profile: QoSProfile | int, **_ignored: Any
    ) -> Publisher:
        """Create a publisher of ``msg_type`` on ``topic`` (ROS name) with ``qos_profile`` (or a depth)."""
        publisher = self._make_publisher(msg_type, topic, coerce_qos(qos_profile))
        self._publishers.append(publisher)
        self._context.entities_changed()
        return publisher

    def _make_publisher(self, msg_type: type, topic: str, profile: QoSProfile) -> Publisher:
        fqn = self.resolve_topic_name(topic)
        dds_topic = self._context.topic(_dds_topic(fqn), msg_type)
        writer = DataWriter(self._context.participant(), dds_topic, to_dds_qos(profile, type_hash(msg_type)))
        return Publisher(writer, msg_type, fqn, profile, context_ok=self._context.ok)

    def entity_guids(self) -> tuple[list[bytes], list[bytes]]:
        """DDS GUIDs of the node's readers and writers (its entities in ros_discovery_info)."""
        readers = [s.guid for s in self._subscriptions] + [s.reader_guid for s in self._services]
        writers = [p.guid for p in self._publishers] + [s.writer_guid for s in self._services]
        return readers, writers + ([self._rosout.guid] if self._rosout is not None else [])

    def create_subscription(
        self,
        msg_type: type,
        topic: str,
        callback: Callable[[Any], Any],
        qos_profile: QoSProfile | int,
        *,
        raw: bool = False,
        **_ignored: Any,
    ) -> Subscription:
        """Create a subscription delivering ``msg_type`` messages of ``topic`` to ``callback`` (with ``raw``:
        their CDR bytes, as rclpy's ``raw=True``)."""
        profile = coerce_qos(qos_profile)
        fqn = self.resolve_topic_name(topic)
        dds_topic = self._context.topic(_dds_topic(fqn), msg_type)
        reader = DataReader(self._context.participant(), dds_topic, to_dds_qos(profile, type_hash(msg_type)))
        subscription = Subscription(reader, msg_type, fqn, callback, profile, raw=raw)
        self._subscriptions.append(subscription)
        self._context.entities_changed()
        return subscription

    def create_timer(
        self, timer_period_sec: float, callback: Callable[[], Any] | None, callback_group: Any = None,
        clock: Clock | None = None,
    ) -> Timer:
        """Call ``callback`` every ``timer_period_sec`` seconds of the node clock (simulated if use_sim_time)."""
        timer = Timer(callback, round(timer_period_sec * _NS), clock or self._clock)
        self._timers.append(timer)
        self._context.entities_version += 1
        if self.executor is not None:
            self.executor.wake()
        return timer

    def destroy_publisher(self, publisher: Publisher) -> bool:
        if publisher in self._publishers:
            self._publishers.remove(publisher)
            publisher.destroy()
            self._context.entities_changed()
            return True
        return False

    def destroy_subscription(self, subscription: Subscription) -> bool:
        if subscription in self._subscriptions:
            self._subscriptions.remove(subscription)
            subscription.destroy()
            forget_deleted_entities()  # its read condition went with the reader
            self._context.entities_changed()
            return True
        return False

    def destroy_timer(self, timer: Timer) -> bool:
        if timer in self._timers:
            self._timers.remove(timer)
            timer.destroy()
            self._context.entities_version += 1
            return True
        return False

    def destroy_node(self) -> None:
        """Destroy every entity of the node; DDS peers see its readers and writers disappear."""
        if self.executor is not None:
            self.executor.remove_node(self)
        alive = self._context.ok()
        for publisher in self._publishers:
            if alive:
                publisher.destroy()
        for subscription in self._subscriptions:
            if alive:
                subscription.destroy()
        for service in self._services:
            if alive:
                service.destroy()
        if self._rosout is not None:
            from taiji2_runtime.dds_rclpy import rosout

            rosout.detach(self._logger.name)
            if alive:
                self._rosout.destroy()
            self._rosout = None
        for timer in self._timers:
            timer.destroy()
        self._publishers, self._subscriptions, self._timers, self._services = [], [], [], []
        if alive:
            forget_deleted_entities()  # read conditions went with their readers
        self._context.unregister_node(self)

    # -- graph ---------------------------------------------------------------------------------
    def get_topic_names_and_types(self, no_demangle: bool = False) -> list[tuple[str, list[str]]]:
        """ROS topics (``rt/`` DDS topics) seen in the graph, with their ROS type names, sorted."""
        table: dict[str, set[str]] = {}
        for kind in ("pub", "sub"):
            for topic_name, type_name in self._context.graph_endpoints(kind):
                if not topic_name.startswith("rt/"):
                    continue
                ros_type = ros_type_name(type_name) or type_name
                table.setdefault(topic_name[2:], set()).add(ros_type)
        return sorted((name, sorted(types)) for name, types in table.items())

    def _count(self, kind: str, topic: str) -> int:
        dds = _dds_topic(self.resolve_topic_name(topic))
        return sum(1 for name, _ in self._context.graph_endpoints(kind) if name == dds)

    def count_publishers(self, topic_name: str) -> int:
        return self._count("pub", topic_name)

    def count_subscribers(self, topic_name: str) -> int:
        return self._count("sub", topic_name)

    def __repr__(self) -> str:
        return f"<Node {self.get_fully_qualified_name()} (taiji2_runtime, Cyclone DDS)>"


def steady_clock() -> Clock:
    """A steady (monotonic) clock for wall-time timers that must not follow simulated time."""
    return Clock(clock_type=ClockType.STEADY_TIME)
