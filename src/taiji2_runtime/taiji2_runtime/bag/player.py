"""Publish a bag's messages into the live graph (the ``taiji2 bag play`` engine).

Messages go out byte for byte from the bag (no decode / re-encode: see :mod:`.runtime_adapter`)
with their original timing scaled by ``rate``, or as fast as the subscribers take them
(``fast``). Publishers are reliable keep-all (transient-local for topics recorded from latched
publishers), so a slow subscriber slows the player down instead of losing messages; at the end
the player waits until every subscriber acknowledged everything. With ``clock_hz`` it publishes
``/clock`` from the bag time (the bag's own ``/clock`` topic is then not played).

Types unknown to the runtime are registered from the bag's embedded definitions where the runtime
allows it; a topic that cannot be played (no definition, a definition that differs from the
installed one, no message class) is skipped and reported.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rosbags.interfaces import Connection, ConnectionExtRosbag2

from taiji2_model.contract import CLOCK_TOPIC, CLOCK_TYPE
from taiji2_runtime.bag.reading import check_types, open_reader
from taiji2_runtime.bag.runtime_adapter import is_publish_timeout, message_class, publishable, publisher_qos
from taiji2_runtime.interfaces import typestore
from taiji2_runtime.ros import rclpy

_NS = 1_000_000_000


@dataclass
class PlayOptions:
    """How to play a bag.

    Attributes
    ----------
    bag : pathlib.Path
        Bag directory or storage file.
    rate : float
        Playback speed factor (1: original timing).
    fast : bool
        Ignore the timing: publish as fast as the subscribers take the messages.
    topics : list of str or None
        Play only these topics (names in the bag).
    remap : dict
        ``{bag topic: published topic}``.
    clock_hz : float or None
        Publish ``/clock`` from the bag time at this rate [Hz of wall time]; None: no clock.
    loop : bool
        Start over at the end, until stopped.
    wait_for_subscribers : int
        Before publishing, wait until every played topic has at least this many subscribers.
    wait_timeout_s : float
        Give up waiting for subscribers after this long [s].
    ack_timeout_s : float
        At the end, wait at most this long [s] for the subscribers' acknowledgements.
    """

    bag: Path
    rate: float = 1.0
    fast: bool = False
    topics: list[str] | None = None
    remap: dict[str, str] = field(default_factory=dict)
    clock_hz: float | None = None
    loop: bool = False
    wait_for_subscribers: int = 0
    wait_timeout_s: float = 30.0
    ack_timeout_s: float = 30.0


@dataclass
class PlayReport:
    """Outcome of :meth:`Player.run`.

    Attributes
    ----------
    published : dict
        Messages published per bag topic.
    skipped : dict
        Topics not played, with the reason.
    unacknowledged : list of str
        Topics whose subscribers did not acknowledge everything within the timeout.
    clock_messages : int
        ``/clock`` messages published.
    elapsed_s : float
        Wall time of the whole run [s] (waiting for subscribers included).
    playing_s : float
        Wall time from the first to the last published message [s].
    acked_after_s : float
        Wall time from the last published message until every subscriber acknowledged [s].
    bag_span_s : float
        Bag time covered by the played messages [s] (all loops).
    loops : int
        Passes over the bag.
    """

    published: dict[str, int]
    skipped: dict[str, str]
    unacknowledged: list[str]
    clock_messages: int
    elapsed_s: float
    playing_s: float
    acked_after_s: float
    bag_span_s: float
    loops: int


@dataclass
class _Output:
    connection: Connection
    publisher: Any
    cls: type
    name: str


class Player:
    """Plays one bag through publishers of ``node``.

    Parameters
    ----------
    node : rclpy.node.Node
        Node that owns the publishers.
    options : PlayOptions
        What and how to play.
    log : callable
        Receives one-line progress / warning messages.

    Raises
    ------
    BagError
        If the bag cannot be read.
    ValueError
        If the options are inconsistent (rate <= 0, unknown topics).
    """

    def __init__(self, node: Any, options: PlayOptions, log: Callable[[str], None] | None = None) -> None:
        if not options.rate > 0:
            raise ValueError(f"--rate must be > 0, got {options.rate}")
        if options.clock_hz is not None and not options.clock_hz > 0:
            raise ValueError(f"--clock rate must be > 0 Hz, got {options.clock_hz}")
        self.node = node
        self.options = options
        self._log = log or (lambda text: print(text, file=sys.stderr, flush=True))
        self._outputs: dict[int, _Output] = {}
        self.skipped: dict[str, str] = {}
        self._clock_publisher: Any = None
        self._clock_cls: type | None = None
        self._published: dict[str, int] = {}
        self._clock_count = 0
        self._first_publish: float | None = None
        self._last_publish = 0.0
        self._bag_span_ns = 0
        with open_reader(options.bag) as reader:
            connections = list(reader.connections)
        self._prepare(connections)

    # -- setup -----------------------------------------------------------------------------------
    def _prepare(self, connections: list[Connection]) -> None:
        options = self.options
        names = {c.topic for c in connections}
        if options.topics:
            unknown = [t for t in options.topics if t not in names]
            if unknown:
                raise ValueError(f"{options.bag}: no topic {', '.join(unknown)} in the bag "
                                 f"(it has {', '.join(sorted(names)) or 'none'})")
        checks = check_types(connections, typestore())
        used_names: dict[str, str] = {}
        for connection in connections:
            topic = connection.topic
            if options.topics and topic not in options.topics:
                continue
            if options.clock_hz is not None and topic == CLOCK_TOPIC:
                self._skip(topic, "replaced by --clock")
                continue
            check = checks[connection.msgtype]
            if not check.usable:
                self._skip(topic, f"{connection.msgtype}: {check.note}")
                continue
            cls = message_class(connection.msgtype)
            if cls is None:
                self._skip(topic, f"{connection.msgtype}: no message class in this runtime")
                continue
            name = options.remap.get(topic, topic)
            if used_names.get(name, connection.msgtype) != connection.msgtype:
                self._skip(topic, f"{connection.msgtype}: {name} is already played with type {used_names[name]}")
                continue
            used_names[name] = connection.msgtype
            qos_list = connection.ext.offered_qos_profiles if isinstance(connection.ext, ConnectionExtRosbag2) else []
            publisher = self.node.create_publisher(cls, name, publisher_qos(list(qos_list)))
            self._outputs[connection.id] = _Output(connection, publisher, cls, name)
            self._published.setdefault(topic, 0)
            if check.note:
                self._log(f"{topic}: {connection.msgtype} {check.note}")
        if options.clock_hz is not None:
            self._clock_cls = message_class(CLOCK_TYPE)
            self._clock_publisher = self.node.create_publisher(self._clock_cls, CLOCK_TOPIC, publisher_qos([]))

    def _skip(self, topic: str, reason: str) -> None:
        self.skipped[topic] = reason
        self._log(f"warning: not playing {topic}: {reason}")

    # -- running ---------------------------------------------------------------------------------
    def wait_for_subscribers(self, stop: Callable[[], bool]) -> None:
        """Block until every played topic has ``wait_for_subscribers`` subscribers.

        Raises
        ------
        RuntimeError
            If they do not appear within ``wait_timeout_s``.
        """
        wanted = self.options.wait_for_subscribers
        if wanted <= 0:
            return
        deadline = time.monotonic() + self.options.wait_timeout_s
        while not stop():
            lacking = sorted({o.name for o in self._outputs.values() if o.publisher.get_subscription_count() < wanted})
            if not lacking:
                return
            if time.monotonic() > deadline:
                raise RuntimeError(f"{self.options.bag}: fewer than {wanted} subscriber(s) on {', '.join(lacking)} "
                                   f"after {self.options.wait_timeout_s:g} s")
            time.sleep(0.02)

    def _publish(self, publisher: Any, sample: Any, topic: str, stop: Callable[[], bool]) -> bool:
        give_up = time.monotonic() + self.options.ack_timeout_s
        while True:
            try:
                publisher.publish(sample)
                return True
            except Exception as exc:
                if not is_publish_timeout(exc):
                    raise
                if stop():
                    return False
                if time.monotonic() > give_up:
                    raise RuntimeError(f"subscribers of {topic} stopped taking messages "
                                       f"(nothing accepted for {self.options.ack_timeout_s:g} s)") from None

    def _publish_clock(self, stamp_ns: int, stop: Callable[[], bool]) -> None:
        msg = self._clock_cls()
        msg.clock.sec, msg.clock.nanosec = divmod(int(stamp_ns), _NS)
        if self._publish(self._clock_publisher, msg, CLOCK_TOPIC, stop):
            self._clock_count += 1

    def run(self, stop: Callable[[], bool] = lambda: False) -> PlayReport:
        """Play (looping if asked) until the end or ``stop()``; then wait for acknowledgements."""
        started = time.monotonic()
        self.wait_for_subscribers(stop)
        loops = 0
        while not stop():
            self._play_once(stop)
            loops += 1
            if not self.options.loop or not self._outputs:
                break
        unacked = self._wait_acked()
        end = time.monotonic()
        playing = self._last_publish - self._first_publish if self._first_publish is not None else 0.0
        acked_after = end - self._last_publish if self._first_publish is not None else 0.0
        return PlayReport(dict(self._published), dict(self.skipped), unacked, self._clock_count,
                          end - started, playing, acked_after, self._bag_span_ns / _NS, loops)

    def _play_once(self, stop: Callable[[], bool]) -> None:
        with open_reader(self.options.bag) as reader:
            connections = [o.connection for o in self._outputs.values()]
            if connections:
                first, last = self._stream(reader.messages(connections), stop)
                if first is not None:
                    self._bag_span_ns += last - first

    def _stream(self, stream: Iterator[tuple[Connection, int, bytes]],
                stop: Callable[[], bool]) -> tuple[int | None, int]:
        """Publish ``stream`` with the configured timing; returns the first and last bag stamps [ns]."""
        options = self.options
        outputs = self._outputs
        published = self._published
        clock = self._clock_publisher is not None
        clock_step_ns = int(_NS / options.clock_hz * (1.0 if options.fast else options.rate)) if clock else 0
        last_clock_ns = -(2**62)
        start_wall: float | None = None
        start_bag: int | None = None
        last_bag = 0
        checked = 0
        for connection, stamp_ns, data in stream:
            output = outputs.get(connection.id)
            if output is None:
                continue
            if start_wall is None or start_bag is None:
                start_wall, start_bag = time.monotonic(), stamp_ns
                if self._first_publish is None:
                    self._first_publish = start_wall
            if not options.fast:
                target = start_wall + (stamp_ns - start_bag) / _NS / options.rate
                while True:
                    remaining = target - time.monotonic()
                    if remaining <= 0 or stop():
                        break
                    if clock:
                        now_bag = start_bag + int((time.monotonic() - start_wall) * options.rate * _NS)
                        if now_bag - last_clock_ns >= clock_step_ns:
                            self._publish_clock(now_bag, stop)
                            last_clock_ns = now_bag
                        remaining = min(remaining, 1.0 / options.clock_hz)
                    time.sleep(min(remaining, 0.05))
            if clock and stamp_ns - last_clock_ns >= clock_step_ns:
                self._publish_clock(stamp_ns, stop)
                last_clock_ns = stamp_ns
            if not self._publish(output.publisher, publishable(data, output.cls), output.name, stop):
                break
            published[connection.topic] += 1
            self._last_publish = time.monotonic()
            last_bag = stamp_ns
            checked += 1
            if checked >= 256:
                checked = 0
                if stop():
                    break
        return start_bag, last_bag

    def _wait_acked(self) -> list[str]:
        timeout = rclpy.duration.Duration(seconds=self.options.ack_timeout_s)
        unacked = []
        publishers = [(o.name, o.publisher) for o in self._outputs.values()]
        if self._clock_publisher is not None:
            publishers.append((CLOCK_TOPIC, self._clock_publisher))
        for name, publisher in publishers:
            try:
                if not publisher.wait_for_all_acked(timeout):
                    unacked.append(name)
            except Exception:  # a publisher of a shut-down context
                unacked.append(name)
        return unacked

    @property
    def published_count(self) -> int:
        """Messages published so far (all topics, all loops)."""
        return sum(self._published.values())

    @property
    def topics(self) -> dict[str, str]:
        """``{bag topic: published topic}`` of the topics being played."""
        return {o.connection.topic: o.name for o in self._outputs.values()}
