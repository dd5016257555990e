"""The few places where recording and playing differ between real rclpy and the embedded runtime.

Everything else in the recorder and player is plain rclpy API through :mod:`taiji2_runtime.ros`.

=====================  =====================================  ======================================
need                   rclpy                                   embedded runtime (Cyclone DDS)
=====================  =====================================  ======================================
raw bytes on receive   ``create_subscription(..., raw=True)``  the same (the reader's sample bytes)
publish raw bytes      ``publisher.publish(bytes)``            sample whose ``serialize()`` returns
                                                               the bytes (no decode / re-encode)
publishers' QoS        ``get_publishers_info_by_topic``        DDS built-in publication topic
=====================  =====================================  ======================================

The bytes are always the CDR stream with its 4-byte encapsulation header, as stored in bags.
"""

from __future__ import annotations

import time
from functools import cache
from typing import Any

from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

from taiji2_runtime.interfaces import split_type
from taiji2_runtime.ros import RUNTIME, messages, rclpy

_ZERO = QosTime(0, 0)


def message_class(msgtype: str) -> type | None:
    """The runtime's message class of ``pkg/msg/Name``, or None if the runtime does not know it."""
    try:
        pkg, _kind, name = split_type(msgtype)
        return getattr(getattr(messages, pkg), name)
    except (AttributeError, ImportError, KeyError, ValueError, TypeError):
        return None


def raw_subscription_kwargs() -> dict[str, Any]:
    """Keyword arguments of ``create_subscription`` that deliver serialised bytes (both runtimes support them:
    a recorder stores what it received without deserialising and serialising it again)."""
    return {"raw": True}


def serialize(msg: Any) -> bytes:
    """CDR bytes (with encapsulation header) of a runtime message object."""
    if RUNTIME == "rclpy":
        from rclpy.serialization import serialize_message

        return bytes(serialize_message(msg))
    return bytes(msg.serialize())


def deserialize(data: bytes, cls: type) -> Any:
    """Runtime message object of class ``cls`` from CDR bytes."""
    if RUNTIME == "rclpy":
        from rclpy.serialization import deserialize_message

        return deserialize_message(data, cls)
    return cls.deserialize(data)


def to_cdr(payload: Any) -> bytes:
    """What a subscription delivered (bytes with ``raw=True``, else a message) as CDR bytes."""
    if isinstance(payload, bytes | bytearray | memoryview):
        return bytes(payload)
    return serialize(payload)


class _Preserialized:
    """Stands in for ``IdlStruct.serialize``: returns the stored bytes whatever the arguments."""

    __slots__ = ("data",)

    def __init__(self, data: bytes) -> None:
        self.data = data

    def __call__(self, *_args: Any, **_kwargs: Any) -> bytes:
        return self.data


@cache
def _supports_preserialized(cls: type) -> bool:
    try:
        sample = object.__new__(cls)
        sample.serialize = _Preserialized(b"\x00\x01\x00\x00")
        return isinstance(sample, cls) and sample.serialize() == b"\x00\x01\x00\x00"
    except Exception:
        return False


def publishable(data: bytes, cls: type) -> Any:
    """An object that ``publisher.publish`` sends as exactly ``data`` (CDR bytes of a ``cls`` message)."""
    if RUNTIME == "rclpy":
        return data  # rclpy publishes serialised messages given as bytes
    if _supports_preserialized(cls):
        sample = object.__new__(cls)
        sample.serialize = _Preserialized(data)
        return sample
    return cls.deserialize(data)


def is_publish_timeout(exc: BaseException) -> bool:
    """True if a publish failed only because a reliable keep-all writer's history is full (retry)."""
    code = getattr(exc, "code", None)
    text = str(exc).lower()
    return code == -10 or "timeout" in text or "timed out" in text


# -- publishers' QoS ---------------------------------------------------------------------------
def _qos(reliable: bool, transient_local: bool, keep_all: bool, depth: int) -> Qos:
    return Qos(QosHistory.KEEP_ALL if keep_all else QosHistory.KEEP_LAST, int(depth),
               QosReliability.RELIABLE if reliable else QosReliability.BEST_EFFORT,
               QosDurability.TRANSIENT_LOCAL if transient_local else QosDurability.VOLATILE,
               _ZERO, _ZERO, QosLiveliness.AUTOMATIC, _ZERO, False)


def _name(value: Any) -> str:
    return str(getattr(value, "name", value)).upper()


class PublisherQosProbe:
    """Offered QoS of the publishers of a topic in the live graph, as rosbags :class:`Qos` records."""

    def __init__(self, node: Any) -> None:
        self._node = node
        self._reader: Any = None
        self._cache: dict[Any, tuple[str, Any]] = {}

    def offered(self, topic: str) -> list[Qos]:
        """One :class:`Qos` per publisher of ``topic`` (empty when none is known)."""
        if hasattr(self._node, "get_publishers_info_by_topic"):
            result = []
            for info in self._node.get_publishers_info_by_topic(topic):
                profile = info.qos_profile
                result.append(_qos("RELIABLE" in _name(profile.reliability),
                                   "TRANSIENT_LOCAL" in _name(profile.durability),
                                   "KEEP_ALL" in _name(profile.history), getattr(profile, "depth", 0)))
            return result
        return self._embedded(topic)

    def _embedded(self, topic: str) -> list[Qos]:
        from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication
        from cyclonedds.core import Policy

        if self._reader is None:
            self._reader = BuiltinDataReader(self._node.context.participant(), BuiltinTopicDcpsPublication)
            deadline = time.monotonic() + 0.2  # the first take may miss what discovery already knows
            while time.monotonic() < deadline and not self._take():
                time.sleep(0.02)
        self._take()
        result = []
        for dds_topic, qos in self._cache.values():
            if dds_topic != "rt" + topic:
                continue
            try:
                reliable = "BestEffort" not in str(qos[Policy.Reliability])
                transient = "Transient" in str(qos[Policy.Durability])
                history = qos[Policy.History]
                keep_all = "KeepAll" in str(history)
                depth = int(getattr(history, "depth", 0) or 0)
            except Exception:  # a peer without some policy: assume ROS defaults
                reliable, transient, keep_all, depth = True, False, False, 10
            result.append(_qos(reliable, transient, keep_all, depth))
        return result

    def _take(self) -> int:
        taken = 0
        for sample in self._reader.take(N=10000):
            taken += 1
            if sample.sample_info.instance_state == 16:  # alive
                self._cache[sample.key] = (sample.topic_name, sample.qos)
            else:
                self._cache.pop(sample.key, None)
        return taken


def subscription_qos(offered: list[Qos]) -> Any:
    """rclpy QoS for a lossless subscription that matches every offered profile.

    Reliable when every publisher is reliable (a reliable reader would not match a best-effort
    writer), transient-local when every publisher is (to get latched samples), keep-all.
    """
    q = rclpy.qos
    reliable = bool(offered) and all(o.reliability == QosReliability.RELIABLE for o in offered)
    transient = bool(offered) and all(o.durability == QosDurability.TRANSIENT_LOCAL for o in offered)
    return q.QoSProfile(
        history=q.HistoryPolicy.KEEP_ALL,
        reliability=q.ReliabilityPolicy.RELIABLE if reliable else q.ReliabilityPolicy.BEST_EFFORT,
        durability=q.DurabilityPolicy.TRANSIENT_LOCAL if transient else q.DurabilityPolicy.VOLATILE)


def publisher_qos(recorded: list[Qos]) -> Any:
    """rclpy QoS to replay a topic losslessly: reliable keep-all, transient-local if it was latched."""
    q = rclpy.qos
    transient = bool(recorded) and all(o.durability == QosDurability.TRANSIENT_LOCAL for o in recorded)
    return q.QoSProfile(
        history=q.HistoryPolicy.KEEP_ALL, reliability=q.ReliabilityPolicy.RELIABLE,
        durability=q.DurabilityPolicy.TRANSIENT_LOCAL if transient else q.DurabilityPolicy.VOLATILE)


def diagnostic_array_class() -> type:
    """``diagnostic_msgs/DiagnosticArray`` of the running client library."""
    return messages.diagnostic_msgs.DiagnosticArray


def diagnostic_array(node: Any, level_name: str, message: str, values: dict[str, Any]) -> Any:
    """A one-status DiagnosticArray named after ``node``, ``level_name`` in OK/WARN/ERROR, values as text."""
    d = messages.diagnostic_msgs
    status = d.DiagnosticStatus(name=node.get_name(), message=message, hardware_id="taiji2_bag_record")
    status.level = getattr(d.DiagnosticStatus, level_name)
    status.values = [d.KeyValue(key=str(k), value=str(v)) for k, v in values.items()]
    array = d.DiagnosticArray()
    array.header.stamp = node.get_clock().now().to_msg()
    array.status = [status]
    return array
