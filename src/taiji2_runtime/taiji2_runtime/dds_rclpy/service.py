"""A ROS 2 service server over Cyclone DDS, answering rmw_cyclonedds_cpp clients (``ros2 param`` etc.).

Endpoints as rmw_cyclonedds_cpp creates them: a reader on ``rq<service>Request`` and a writer on
``rr<service>Reply`` (ROS 2 services QoS: reliable, volatile, keep-last 10), both carrying
``serviceid=<id>;typehash=<hash>;`` in USER_DATA (clients look for a reply writer with the same
service id as a matched request reader before they call it available). The reply repeats the
request's header (client writer handle, sequence number), which is how the client pairs them.
"""

from __future__ import annotations

import uuid
from collections.abc import Callable
from typing import Any

from cyclonedds.core import InstanceState, Policy, Qos, ReadCondition, SampleState, ViewState
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader

from taiji2_runtime.dds_rclpy.service_types import service_type_hash, wire_class

#: rmw_qos_profile_services_default
_DEPTH = 10


def _qos(user_data: str) -> Qos:
    return Qos(Policy.Reliability.Reliable(0), Policy.Durability.Volatile, Policy.History.KeepLast(_DEPTH),
               Policy.DataRepresentation(use_cdrv0_representation=True),
               Policy.Userdata(user_data.encode("ascii")))


def _service_id(guid: bytes) -> str:
    """rmw_cyclonedds_cpp's text form of a 16-byte client/service id (hex bytes joined by dots)."""
    return ".".join(f"{b:x}" if i else f"{b:02x}" for i, b in enumerate(guid))


class Service:
    """Answers requests of service type ``srv`` (``pkg/srv/Name``) on ``service_name`` with ``handler``."""

    def __init__(self, context: Any, srv: str, service_name: str,
                 handler: Callable[[Any, Any], Any]) -> None:
        participant = context.participant()
        self.srv_type = srv
        self.service_name = service_name
        self._handler = handler
        self._request_type = wire_class(srv, "Request")
        self._reply_type = wire_class(srv, "Response")
        self._response_body = self._reply_type.__dataclass_fields__["body"].default_factory
        request_topic = context.topic(f"rq{service_name}Request", self._request_type)
        reply_topic = context.topic(f"rr{service_name}Reply", self._reply_type)
        # any id unique to this server pairs its two endpoints (rmw_cyclonedds_cpp counts per participant)
        service_id = _service_id(uuid.uuid4().bytes)
        self._reader = DataReader(participant, request_topic,
                                  _qos(f"serviceid={service_id};typehash={service_type_hash(srv, 'Request')};"))
        self._writer = DataWriter(participant, reply_topic,
                                  _qos(f"serviceid={service_id};typehash={service_type_hash(srv, 'Response')};"))
        self.read_condition = ReadCondition(self._reader, SampleState.NotRead | ViewState.Any | InstanceState.Any)
        #: GUIDs of the request reader and the reply writer (their GIDs in ros_discovery_info)
        self.reader_guid: bytes = self._reader.get_guid().bytes
        self.writer_guid: bytes = self._writer.get_guid().bytes

    def take(self, max_samples: int) -> list[Any]:
        """Up to ``max_samples`` pending requests (header and body)."""
        if self._reader is None:
            return []
        return [r for r in self._reader.take(N=max_samples) if isinstance(r, self._request_type)]

    def answer(self, request: Any) -> None:
        """Run the handler on one request and send the reply with the request's header."""
        if self._writer is None:
            return
        body = self._handler(request.body, self._response_body())
        self._writer.write(self._reply_type(client_guid=request.client_guid,
                                            sequence_number=request.sequence_number, body=body))

    def destroy(self) -> None:
        reader, writer, self._reader, self._writer = self._reader, self._writer, None, None
        for entity in (reader, writer):
            if entity is not None:
                entity.__del__()
