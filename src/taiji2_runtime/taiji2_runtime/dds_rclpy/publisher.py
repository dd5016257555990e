"""rclpy.publisher.Publisher over a Cyclone DDS DataWriter."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from cyclonedds.core import DDSException
from cyclonedds.pub import DataWriter
from cyclonedds.util import duration

from taiji2_runtime.dds_rclpy.duration import Duration
from taiji2_runtime.dds_rclpy.qos import QoSProfile

#: Longest a reliable write waits for a slow reader before the sample is given up for it [s].
DEFAULT_WRITE_TIMEOUT_S = 30.0


class Publisher:
    """Publishes messages of one type on one topic.

    A reliable writer whose history is full blocks while a matched reliable reader is behind
    (back-pressure, as rmw_cyclonedds does under rclpy). Cyclone returns a timeout after its
    ``max_blocking_time``; the write is then retried until ``write_timeout_s`` has passed, after
    which the sample is given up and counted in :attr:`samples_dropped`: a slow or stalled peer
    never ends the publishing node. A write after the context has shut down is dropped silently.
    """

    def __init__(self, writer: DataWriter, msg_type: type, topic_name: str, qos_profile: QoSProfile,
                 context_ok: Callable[[], bool] = lambda: True) -> None:
        self._writer: DataWriter | None = writer
        #: the writer's DDS GUID (16 bytes): its GID in ros_discovery_info
        self.guid: bytes = writer.get_guid().bytes
        self.msg_type = msg_type
        self._topic_name = topic_name
        self.qos_profile = qos_profile
        self._context_ok = context_ok
        #: see the class docstring [s]
        self.write_timeout_s = DEFAULT_WRITE_TIMEOUT_S
        #: samples given up after ``write_timeout_s`` of back-pressure
        self.samples_dropped = 0

    @property
    def topic_name(self) -> str:
        return self._topic_name

    @property
    def handle(self) -> DataWriter:
        if self._writer is None:
            raise RuntimeError(f"publisher on {self._topic_name} is destroyed")
        return self._writer

    def publish(self, msg: Any) -> None:
        """Send ``msg``.

        Raises
        ------
        TypeError
            If ``msg`` is not an instance of the publisher's message type.
        """
        if not isinstance(msg, self.msg_type):
            raise TypeError(
                f"Expected {self.msg_type.__name__}, got {type(msg).__name__} on topic {self._topic_name}"
            )
        if self._writer is None and not self._context_ok():
            return
        deadline: float | None = None
        while True:
            try:
                self.handle.write(msg)
                return
            except DDSException as exc:
                if not self._context_ok():
                    return  # shutting down: peers are gone or the participant is deleted
                if exc.code != DDSException.DDS_RETCODE_TIMEOUT:
                    raise
            # a reliable reader is behind: wait for it, bounded by write_timeout_s
            now = time.monotonic()
            deadline = now + self.write_timeout_s if deadline is None else deadline
            if now >= deadline:
                self.samples_dropped += 1
                return

    def get_subscription_count(self) -> int:
        return self.handle.get_publication_matched_status().current_count

    def wait_for_all_acked(self, timeout: Duration = Duration(seconds=-1)) -> bool:  # noqa: B008
        """Block until every matched reliable reader has acknowledged all samples; False on timeout."""
        ns = timeout.nanoseconds
        span = duration(infinite=True) if ns < 0 else ns
        try:
            self.handle.wait_for_acks(span)
        except AttributeError:
            # cyclonedds 11.0.1 raises AttributeError instead of reporting the timeout
            return False
        except Exception:
            return False
        return True

    def destroy(self) -> None:
        writer, self._writer = self._writer, None
        if writer is not None:
            writer.__del__()
