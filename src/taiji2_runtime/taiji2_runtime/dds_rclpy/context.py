"""rclpy.context.Context over one Cyclone DDS domain participant.

A context owns one DomainParticipant (as rmw_cyclonedds_cpp does), the DDS topics created in
it, the graph cache read from the DDS builtin topics, and the list of executors to wake on
shutdown. Default Cyclone configuration: loopback only, multicast off, unicast discovery to
127.0.0.1; ``CYCLONEDDS_URI`` replaces it entirely.
"""

from __future__ import annotations

import os
import tempfile
import threading
from collections.abc import Callable, Sequence
from typing import Any

from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication, BuiltinTopicDcpsSubscription
from cyclonedds.core import DDSException, Policy, Qos
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.topic import Topic

# the default configuration lives in a module of its own (standard library only): `taiji2
# --print-cyclonedds-config` prints it on a ROS 2 machine without the cyclonedds Python package
from taiji2_runtime.cyclonedds_config import DEFAULT_CYCLONEDDS_CONFIG, MAX_PARTICIPANTS_PER_HOST  # noqa: F401
from taiji2_runtime.dds_rclpy.arguments import RosArguments, parse_ros_args
from taiji2_runtime.dds_rclpy.exceptions import DdsUnavailableError, NotInitializedException
from taiji2_runtime.dds_rclpy.topics import create_topic

#: Shutdown reason prefix when a node turned out to duplicate another node's name.
DUPLICATE_NODE_NAME = "duplicate node name"

_ALIVE = 16  # DDS_IST_ALIVE
_domains: dict[int, Domain] = {}
_domains_lock = threading.Lock()


def ros_domain_id() -> int:
    """Domain id from ``ROS_DOMAIN_ID`` (default 0).

    Raises
    ------
    DdsUnavailableError
        If ``ROS_DOMAIN_ID`` is not an integer in [0, 232].
    """
    text = os.environ.get("ROS_DOMAIN_ID", "").strip()
    if not text:
        return 0
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= 232:
        raise DdsUnavailableError(f"ROS_DOMAIN_ID={text!r} is not an integer in [0, 232]")
    return value


def _capture_stderr(create: Callable[[], Any]) -> tuple[Any, str]:
    """Run ``create`` with the C-level stderr captured, so DDS errors can be reported in one line."""
    with tempfile.TemporaryFile(mode="w+b") as sink:
        saved = os.dup(2)
        os.dup2(sink.fileno(), 2)
        try:
            result = create()
            error = None
        except DDSException as exc:
            result, error = None, exc
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        sink.seek(0)
        text = sink.read().decode(errors="replace")
    if error is not None:
        raise DdsUnavailableError(_dds_failure_message(text, error)) from error
    return result, text


def _dds_failure_message(captured: str, error: Exception) -> str:
    detail = " ".join(line.split(":", 1)[-1].strip() for line in captured.splitlines() if line.strip())
    source = "CYCLONEDDS_URI" if os.environ.get("CYCLONEDDS_URI") else "the default loopback configuration"
    reason = detail or str(error)
    return f"cannot start DDS on domain {ros_domain_id()} with {source}: {reason}"


def _domain_participant(domain_id: int, user_data: bytes) -> DomainParticipant:
    with _domains_lock:
        if domain_id not in _domains and not os.environ.get("CYCLONEDDS_URI"):
            _domains[domain_id], _ = _capture_stderr(lambda: Domain(domain_id, DEFAULT_CYCLONEDDS_CONFIG))
    qos = Qos(Policy.Userdata(user_data))
    participant, _ = _capture_stderr(lambda: DomainParticipant(domain_id, qos=qos))
    return participant


class Context:
    """Initialization state of the runtime: arguments, DDS participant, executors to wake."""

    def __init__(self) -> None:
        self._lock = threading.RLock()
        self._initialized = False
        self._shutdown_reason: str | None = None
        self._args = RosArguments()
        self._participant: DomainParticipant | None = None
        self._topics: dict[str, tuple[Topic, type]] = {}
        self._executors: list[Any] = []
        self._nodes: dict[str, Any] = {}  # fully qualified name -> Node of this context
        self._on_shutdown: list[Callable[[], None]] = []
        self._graph_readers: tuple[BuiltinDataReader, BuiltinDataReader] | None = None
        self._graph: dict[str, dict[Any, Any]] = {"pub": {}, "sub": {}}
        self._discovery: Any = None  # DiscoveryInfo (ros_discovery_info), created with the participant
        self._start_ns = 0
        self.domain_id = 0
        self.entities_version = 0

    # -- lifecycle -----------------------------------------------------------------------------
    def init(self, args: Sequence[str] | None = None, *, domain_id: int | None = None) -> None:
        """Parse ``args`` (full argv) and mark the context initialized; DDS starts lazily."""
        with self._lock:
            if self._initialized:
                raise RuntimeError("Context.init() must only be called once")
            self._args = parse_ros_args(args)
            self.domain_id = ros_domain_id() if domain_id is None else domain_id
            self._initialized = True
            self._shutdown_reason = None

    def ok(self) -> bool:
        return self._initialized and self._shutdown_reason is None

    @property
    def shutdown_reason(self) -> str | None:
        return self._shutdown_reason

    def shutdown(self, reason: str = "shutdown") -> None:
        """Shut down: wake executors, then delete the participant so peers drop it at once."""
        with self._lock:
            if not self._initialized:
                raise NotInitializedException()
            if self._shutdown_reason is not None:
                return
            self._shutdown_reason = reason
            callbacks = list(self._on_shutdown)
            executors = list(self._executors)
        for callback in callbacks:
            callback()
        for executor in executors:
            executor.wake()
        self._release_dds()

    def try_shutdown(self, reason: str = "shutdown") -> None:
        if self._initialized and self._shutdown_reason is None:
            self.shutdown(reason)

    def on_shutdown(self, callback: Callable[[], None]) -> None:
        self._on_shutdown.append(callback)

    def _release_dds(self) -> None:
        with self._lock:
            participant, self._participant = self._participant, None
            self._topics.clear()
            self._graph_readers = None
            self._discovery = None
        if participant is not None:
            # Deleting the participant (and with it every reader/writer) sends the SPDP dispose,
            # so peers drop us at once instead of after the lease duration.
            participant.__del__()
            forget_deleted_entities()

    # -- DDS entities --------------------------------------------------------------------------
    @property
    def args(self) -> RosArguments:
        return self._args

    def participant(self) -> DomainParticipant:
        """The context's DomainParticipant, created on first use.

        Raises
        ------
        NotInitializedException
            If the context is not initialized or already shut down.
        DdsUnavailableError
            If DDS cannot start (no usable interface, bad CYCLONEDDS_URI, ...).
        """
        with self._lock:
            if not self.ok():
                raise NotInitializedException()
            if self._participant is None:
                from taiji2_runtime.dds_rclpy.discovery_info import (
                    DiscoveryInfo,
                    participant_user_data,
                    process_start_ns,
                )

                self._start_ns = process_start_ns()
                self._participant = _domain_participant(self.domain_id, participant_user_data(self._start_ns))
                self._discovery = DiscoveryInfo(self._participant, self._start_ns)
            return self._participant

    def topic(self, dds_name: str, dds_type: type) -> Topic:
        """The DDS topic ``dds_name`` of this participant (created once, type checked)."""
        with self._lock:
            if dds_name in self._topics:
                topic, known_type = self._topics[dds_name]
                if known_type is not dds_type:
                    raise TypeError(
                        f"topic {dds_name!r} is already used with type {known_type.__name__}, "
                        f"not {dds_type.__name__}"
                    )
                return topic
            topic = create_topic(self.participant(), dds_name, dds_type)
            self._topics[dds_name] = (topic, dds_type)
            return topic

    def register_node(self, node: Any) -> None:
        """Claim a node's name: refused at once within the process, announced on ros_discovery_info."""
        from taiji2_runtime.dds_rclpy.exceptions import NodeNameNonUniqueError

        fqn = node.get_fully_qualified_name()
        with self._lock:
            if fqn in self._nodes:
                raise NodeNameNonUniqueError(f"a node named {fqn!r} already exists in this process")
            self.participant()
            self._nodes[fqn] = node
        self.entities_changed()

    def unregister_node(self, node: Any) -> None:
        with self._lock:
            self._nodes.pop(node.get_fully_qualified_name(), None)
        self.entities_changed()

    def entities_changed(self) -> None:
        """A node, reader or writer came or went: wake waitsets and tell the graph (ros_discovery_info)."""
        with self._lock:
            self.entities_version += 1
            if self._discovery is None or not self.ok():
                return
            self._discovery.announce([(node.get_namespace(), node.get_name(), *node.entity_guids())
                                      for node in self._nodes.values()])

    def graph_nodes(self) -> list[Any]:
        """Every node of the domain (``GraphNode``: namespace, name, participant), this context's included."""
        with self._lock:
            self.participant()
            return self._discovery.nodes()

    def check_node_names(self) -> None:
        """Shut down if one of this context's nodes duplicates an earlier embedded node elsewhere."""
        with self._lock:
            ok = self._discovery is not None and self.ok()
            conflict = self._discovery.conflict(set(self._nodes)) if ok else None
        if conflict is not None:
            self.shutdown(f"{DUPLICATE_NODE_NAME}: {conflict}")

    def add_executor(self, executor: Any) -> None:
        with self._lock:
            if executor not in self._executors:
                self._executors.append(executor)

    def remove_executor(self, executor: Any) -> None:
        with self._lock:
            if executor in self._executors:
                self._executors.remove(executor)

    # -- graph ---------------------------------------------------------------------------------
    def graph_endpoints(self, kind: str) -> list[tuple[str, str]]:
        """Alive (DDS topic name, DDS type name) of every remote and local endpoint; kind 'pub'|'sub'."""
        with self._lock:
            if self._graph_readers is None:
                participant = self.participant()
                self._graph_readers = (
                    BuiltinDataReader(participant, BuiltinTopicDcpsPublication),
                    BuiltinDataReader(participant, BuiltinTopicDcpsSubscription),
                )
            reader = self._graph_readers[0 if kind == "pub" else 1]
            cache = self._graph[kind]
            for sample in reader.take(N=100000):
                if sample.sample_info.instance_state == _ALIVE:
                    cache[sample.key] = (sample.topic_name, sample.type_name)
                else:
                    cache.pop(sample.key, None)
            return list(cache.values())


_default_context = Context()


def get_default_context() -> Context:
    """The process-wide default context (rclpy.utilities.get_default_context)."""
    return _default_context


def forget_deleted_entities() -> None:
    """Drop from cyclonedds' registry the Python entities whose DDS entity is gone (deleted with their
    participant: readers, writers, read conditions, topics).

    cyclonedds-python's ``Entity.__del__`` deletes the handle it holds if that handle is still in its
    registry. A stale reader object finalized later (by the garbage collector, at any allocation)
    would call ``dds_delete`` on a handle that is gone; forgotten, their finalizers do nothing.
    (Cyclone draws handles at random from 2**31 values, so that call deleting a *new* entity is
    improbable; the segmentation fault in ``Topic()`` once blamed on it was a race in cyclonedds'
    type library, see :mod:`.topics`.)
    """
    from cyclonedds.core import Entity

    registry = Entity._entities
    for ref, entity in list(registry.items()):
        if entity is not None and entity._get_parent(ref) < 0:  # a negative return code: no such entity (deleted)
            registry.pop(ref, None)
