"""rclpy.publisher.Publisher over a Cyclone DDS DataWriter."""

from __future__ import annotations

from typing import Any

from cyclonedds.pub import DataWriter
from cyclonedds.util import duration

from .duration import Duration
from .qos import QoSProfile


class Publisher:
    """Publishes messages of one type on one topic."""

    def __init__(self, writer: DataWriter, msg_type: type, topic_name: str, qos_profile: QoSProfile) -> None:
        self._writer: DataWriter | None = writer
        self.msg_type = msg_type
        self._topic_name = topic_name
        self.qos_profile = qos_profile

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
        self.handle.write(msg)

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
