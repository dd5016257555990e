"""rclpy.subscription.Subscription over a Cyclone DDS DataReader."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from cyclonedds._clayer import ddspy_take
from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState
from cyclonedds.sub import DataReader

from taiji2_runtime.dds_rclpy.qos import QoSProfile


class Subscription:
    """Delivers messages of one type on one topic to ``callback`` from an executor.

    With ``raw`` (rclpy's ``create_subscription(..., raw=True)``) the callback gets each sample's CDR bytes
    as the reader holds them (encapsulation header first, padded to a multiple of 4 octets, as rmw delivers
    them), never deserialised: a recorder stores them as they are."""

    def __init__(
        self,
        reader: DataReader,
        msg_type: type,
        topic_name: str,
        callback: Callable[[Any], Any],
        qos_profile: QoSProfile,
        raw: bool = False,
    ) -> None:
        self._reader: DataReader | None = reader
        #: the reader's DDS GUID (16 bytes): its GID in ros_discovery_info
        self.guid: bytes = reader.get_guid().bytes
        self.msg_type = msg_type
        self._topic_name = topic_name
        self.callback = callback
        self.qos_profile = qos_profile
        self.raw = raw
        self.read_condition = ReadCondition(reader, SampleState.NotRead | ViewState.Any | InstanceState.Any)

    @property
    def topic_name(self) -> str:
        return self._topic_name

    @property
    def handle(self) -> DataReader:
        if self._reader is None:
            raise RuntimeError(f"subscription on {self._topic_name} is destroyed")
        return self._reader

    def get_publisher_count(self) -> int:
        return self.handle.get_subscription_matched_status().current_count

    def take(self, max_samples: int) -> list[Any]:
        """Up to ``max_samples`` received messages, oldest first (invalid/dispose samples skipped)."""
        if self._reader is None:
            return []
        if self.raw:
            taken = ddspy_take(self._reader._ref, SampleState.Any | ViewState.Any | InstanceState.Any, max_samples)
            if isinstance(taken, int):
                raise RuntimeError(f"take on {self._topic_name} failed: DDS return code {taken}")
            return [data for data, info in taken if info.valid_data]
        return [m for m in self._reader.take(N=max_samples) if isinstance(m, self.msg_type)]

    def destroy(self) -> None:
        reader, self._reader = self._reader, None
        if reader is not None:
            reader.__del__()
