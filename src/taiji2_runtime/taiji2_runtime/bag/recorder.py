"""Record topics of the live ROS 2 graph into a crash-safe bag (the ``taiji2 bag record`` engine).

Uses only the rclpy API of :mod:`taiji2_runtime.ros` (plus :mod:`.runtime_adapter`), so it runs
on real rclpy and on the embedded runtime alike. Topics and types are discovered with
``get_topic_names_and_types`` every ``discovery_period_s`` (topics that appear later are picked
up); each subscription matches its publishers' QoS losslessly (reliable keep-all when they are
reliable, transient-local when they latch). The bag stamp of a message is its receive time (when
its callback runs) on the recorder's clock, as rosbag2 does: system time, or with the node's
``use_sim_time`` the latest ``/clock``, followed in a thread of its own so it stays current while
the executor drains a backlog. The messages themselves are stored byte for byte.

A storage failure (disk full, file-size limit) does not stop the recording: it is logged and
published on ``/diagnostics`` (ERROR, then WARN once writing works again, each naming the count of
messages not recorded); the bag keeps everything written before it (see :mod:`.writer`).
"""

from __future__ import annotations

import re
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from taiji2_model.contract import CLOCK_TOPIC, PROVENANCE_TOPIC
from taiji2_runtime.bag.provenance import recorder_provenance, simulator_provenance
from taiji2_runtime.bag.runtime_adapter import (
    PublisherQosProbe,
    diagnostic_array,
    diagnostic_array_class,
    message_class,
    raw_subscription_kwargs,
    subscription_qos,
    to_cdr,
)
from taiji2_runtime.bag.writer import BagWriter, DefinitionUnavailable
from taiji2_runtime.interfaces import typestore


@dataclass
class RecordOptions:
    """What to record and how.

    Attributes
    ----------
    output : pathlib.Path
        Bag directory to create.
    topics : list of str
        Topics to record (also those that appear later).
    all_topics : bool
        Record every topic (``-a``), except hidden ones unless ``include_hidden``.
    regex : str or None
        Also record topics matching this regular expression.
    exclude : str or None
        Never record topics matching this regular expression.
    include_hidden : bool
        With ``all_topics`` / ``regex``, also record hidden topics (a name part starting with ``_``).
    storage : str
        ``mcap`` or ``sqlite3``.
    max_duration_s : float or None
        Stop after this long [s] on the recorder clock since the first recorded message.
    discovery_period_s : float
        Wall period [s] of topic discovery.
    journal_period_s, segment_period_s : float
        See :class:`~taiji2_runtime.bag.writer.BagWriter`.
    command_line : list of str
        Stored in the provenance.
    custom_data : dict of str to str
        More custom data to store (``--custom-data``; e.g. what a ground recording's run commanded).
    """

    output: Path
    topics: list[str] = field(default_factory=list)
    all_topics: bool = False
    regex: str | None = None
    exclude: str | None = None
    include_hidden: bool = False
    storage: str = "mcap"
    max_duration_s: float | None = None
    discovery_period_s: float = 0.5
    journal_period_s: float = 0.5
    segment_period_s: float = 300.0
    command_line: list[str] = field(default_factory=lambda: list(sys.argv))
    custom_data: dict[str, str] = field(default_factory=dict)


@dataclass
class RecordReport:
    """What a recording holds: ``counts`` per topic, ``skipped`` topics with the reason."""

    path: Path
    counts: dict[str, int]
    types: dict[str, str]
    skipped: dict[str, str]
    missing: list[str]
    #: messages received (in ``counts``) but not written because the storage failed, and the last failure
    dropped: int = 0
    storage_error: str | None = None


class _ClockFollower:
    """The latest ``/clock`` time, taken by its own node and executor in a thread.

    With simulated time the node clock only advances when the executor gets round to the ``/clock``
    subscription, which under load can be many messages later (the executor drains subscriptions
    in batches); a dedicated thread keeps the receive stamps current, as rclcpp's clock thread does
    for rosbag2.
    """

    def __init__(self, node: Any) -> None:
        from taiji2_runtime.ros import messages, rclpy

        self.latest_ns = 0
        self._running = True
        self._node = rclpy.create_node(f"{node.get_name()}_clock", context=node.context)
        qos = rclpy.qos.QoSProfile(depth=1, reliability=rclpy.qos.ReliabilityPolicy.BEST_EFFORT)
        self._node.create_subscription(messages.rosgraph_msgs.Clock, CLOCK_TOPIC, self._on_clock, qos)
        self._executor = rclpy.executors.SingleThreadedExecutor(context=node.context)
        self._executor.add_node(self._node)
        self._thread = threading.Thread(target=self._spin, name="taiji2-bag-clock", daemon=True)
        self._thread.start()

    def _on_clock(self, msg: Any) -> None:
        self.latest_ns = int(msg.clock.sec) * 1_000_000_000 + int(msg.clock.nanosec)

    def _spin(self) -> None:
        while self._running:
            try:
                self._executor.spin_once(timeout_sec=0.1)
            except Exception:  # the context was shut down under us: stop following
                return

    def now_ns(self) -> int:
        """Latest simulated time [ns] (0 before the first /clock)."""
        return self.latest_ns

    def close(self) -> None:
        self._running = False
        self._thread.join(timeout=2.0)
        try:
            self._executor.shutdown()
            self._node.destroy_node()
        except Exception:
            pass


class _NodeClock:
    """Receive stamps from the node clock (system time without simulated time)."""

    def __init__(self, node: Any) -> None:
        self._clock = node.get_clock()

    def now_ns(self) -> int:
        return int(self._clock.now().nanoseconds)

    def close(self) -> None:
        pass


def _uses_sim_time(node: Any) -> bool:
    try:
        return bool(node.get_parameter("use_sim_time").value)
    except Exception:  # a node without the parameter: system time
        return False


def _hidden(topic: str) -> bool:
    return any(part.startswith("_") for part in topic.split("/"))


class Recorder:
    """Subscribes to the selected topics of ``node``'s graph and writes what arrives into a bag.

    Parameters
    ----------
    node : rclpy.node.Node
        Node to subscribe with (its clock stamps the messages).
    options : RecordOptions
        Selection and storage.
    log : callable
        Receives one-line progress / warning messages.

    Raises
    ------
    BagError
        If the output exists or cannot be created.
    ValueError
        If no topic is selected or a regular expression is invalid.
    """

    def __init__(self, node: Any, options: RecordOptions, log: Callable[[str], None] | None = None) -> None:
        if not (options.topics or options.all_topics or options.regex):
            raise ValueError("nothing to record: give topics, -a/--all or -e/--regex")
        try:
            self._include = re.compile(options.regex) if options.regex else None
            self._exclude = re.compile(options.exclude) if options.exclude else None
        except re.error as exc:
            raise ValueError(f"invalid topic regular expression: {exc}") from None
        self.node = node
        self.options = options
        self._log = log or (lambda text: print(text, file=sys.stderr, flush=True))
        self._store = typestore()
        self.writer = BagWriter(options.output, self._store, storage=options.storage,
                                journal_period_s=options.journal_period_s,
                                segment_period_s=options.segment_period_s)
        for key, value in {**recorder_provenance(options.command_line), **options.custom_data}.items():
            self.writer.set_custom_data(key, value)
        self._probe = PublisherQosProbe(node)
        self._subscriptions: dict[str, Any] = {}
        self._types: dict[str, str] = {}
        self._counts: dict[str, int] = {}
        self._skipped: dict[str, str] = {}
        self._first_stamp_ns: int | None = None
        self._last_discovery = 0.0
        self._clock: _ClockFollower | _NodeClock = _ClockFollower(node) if _uses_sim_time(node) else _NodeClock(node)
        self.stopped = False
        self._storage_failures_reported = (0, True)
        self._diagnostics = node.create_publisher(diagnostic_array_class(), "/diagnostics", 10)
        self.discover()

    # -- selection -------------------------------------------------------------------------------
    def wants(self, topic: str) -> bool:
        """True if ``topic`` is selected for recording."""
        if self._exclude is not None and self._exclude.search(topic):
            return False
        if topic in self.options.topics:
            return True
        if _hidden(topic) and not self.options.include_hidden:
            return False
        if self.options.all_topics:
            return True
        return bool(self._include is not None and self._include.search(topic))

    def discover(self) -> None:
        """Subscribe to selected topics that appeared in the graph since the last call."""
        self._last_discovery = time.monotonic()
        for topic, types in self.node.get_topic_names_and_types():
            if topic in self._subscriptions or topic in self._skipped or not types or not self.wants(topic):
                continue
            self._subscribe(topic, list(types))

    def _subscribe(self, topic: str, types: list[str]) -> None:
        offered = self._probe.offered(topic)
        if not offered:
            return  # only subscribers so far: wait for a publisher to learn its QoS
        usable = [t for t in types if t in self._store.fielddefs and message_class(t) is not None]
        if not usable:
            reason = f"unknown message type {types[0]}" if len(types) == 1 else f"unknown types {', '.join(types)}"
            self._skip(topic, reason)
            return
        msgtype = usable[0]
        if len(types) > 1:
            self._log(f"warning: {topic} is published with several types ({', '.join(types)}); recording {msgtype}")
        try:
            handle = self.writer.add_topic(topic, msgtype, offered)
        except DefinitionUnavailable as exc:  # a definition and its hash from one source, or not the topic
            self._skip(topic, str(exc).strip("'\""))
            return
        cls = message_class(msgtype)
        on_message = self._make_callback(topic, handle)
        self._subscriptions[topic] = self.node.create_subscription(
            cls, topic, on_message, subscription_qos(offered), **raw_subscription_kwargs())
        self._types[topic] = msgtype
        self._counts[topic] = 0
        self._log(f"recording {topic} [{msgtype}]")

    def _skip(self, topic: str, reason: str) -> None:
        self._skipped[topic] = reason
        self._log(f"warning: not recording {topic}: {reason}")

    def _make_callback(self, topic: str, handle: int) -> Callable[[Any], None]:
        writer, counts, clock = self.writer, self._counts, self._clock
        is_provenance = topic == PROVENANCE_TOPIC

        def on_message(payload: Any) -> None:
            data = to_cdr(payload)
            stamp_ns = clock.now_ns()
            if self._first_stamp_ns is None:
                self._first_stamp_ns = stamp_ns
            writer.write(handle, stamp_ns, data)
            counts[topic] += 1
            if is_provenance:
                self._on_provenance(data)

        return on_message

    def _on_provenance(self, data: bytes) -> None:
        try:
            text = self._store.deserialize_cdr(data, "std_msgs/msg/String").data
        except Exception:  # not a std_msgs/String: keep the bytes in the bag, skip the metadata
            return
        for key, value in simulator_provenance(text).items():
            self.writer.set_custom_data(key, value)

    # -- running ---------------------------------------------------------------------------------
    def tick(self) -> None:
        """Periodic work: discovery, closing due journal files, the duration limit. Call often."""
        now = time.monotonic()
        if now - self._last_discovery >= self.options.discovery_period_s:
            self.discover()
        self.writer.poll(now)
        self._report_storage()
        limit = self.options.max_duration_s
        if limit is not None and self._first_stamp_ns is not None:
            if self._clock.now_ns() - self._first_stamp_ns >= limit * 1e9:
                self.stopped = True

    def _report_storage(self) -> None:
        """One log line and one /diagnostics status per storage failure and per recovery."""
        writer = self.writer
        state = (writer.failure_count, writer.storage_error is None)
        if state == self._storage_failures_reported:
            return
        self._storage_failures_reported = state
        if writer.storage_error is not None:
            level, text = "ERROR", (f"bag storage failed ({writer.storage_error}): recording suspended, retried "
                                    f"every {writer.retry_period_s:g} s; {writer.dropped_count} messages not "
                                    f"recorded so far; the bag keeps everything written before")
        else:
            level, text = "WARN", (f"bag storage writing again after {writer.failure_count} failure(s); "
                                   f"{writer.dropped_count} messages not recorded")
        self._log(("error: " if level == "ERROR" else "warning: ") + text)
        self._diagnostics.publish(diagnostic_array(self.node, level, text, {
            "bag": str(self.options.output), "dropped_messages": writer.dropped_count,
            "storage_failures": writer.failure_count}))

    @property
    def message_count(self) -> int:
        """Messages recorded so far."""
        return sum(self._counts.values())

    def close(self) -> RecordReport:
        """Destroy the subscriptions, close the bag, and report what it holds."""
        for subscription in self._subscriptions.values():
            try:
                self.node.destroy_subscription(subscription)
            except Exception:  # the context may already be shut down
                pass
        self._subscriptions.clear()
        self._clock.close()
        self.writer.close()
        self._report_storage()
        missing = [t for t in self.options.topics if t not in self._types and t not in self._skipped]
        return RecordReport(self.options.output, dict(self._counts), dict(self._types), dict(self._skipped),
                            missing, self.writer.dropped_count, self.writer.last_storage_error)
