"""A ROS 2 service server over Cyclone DDS, answering rmw_cyclonedds_cpp clients (``ros2 param`` etc.).

Endpoints as rmw_cyclonedds_cpp creates them: a reader on ``rq<service>Request`` and a writer on
``rr<service>Reply`` (ROS 2 services QoS: reliable, volatile, keep-last 10), both carrying
``serviceid=<id>;typehash=<hash>;`` in USER_DATA (clients look for a reply writer with the same
service id as a matched request reader before they call it available). The reply repeats the
request's header (client writer handle, sequence number), which is how the client pairs them.

A client sees the server's endpoints before the server sees the client's: a request can arrive before
the reply writer has matched the client's reply reader, and a reply written then never reaches it
(volatile), so a client that does not resend (``ros2 param``) waits for ever. Under load that happened in
the rclpy tier (``ros2 param`` on an embedded node, beside two CPU-bound processes: the command hung
past its 180-s bound). rmw_cyclonedds_cpp's ``rmw_send_response`` waits up to 100 ms, blocking, for the
client's reply reader (the ``clientid`` in both client endpoints' USER_DATA). Here the reply is held,
without blocking the executor, and sent once the reader is matched (:meth:`Service.send_held`, every
executor pass); it is dropped when the client's request writer is gone or after ``HOLD_S``.
"""

from __future__ import annotations

import logging
import time
import uuid
from collections.abc import Callable
from typing import Any

from cyclonedds.core import InstanceState, Policy, Qos, ReadCondition, SampleState, ViewState
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader

from taiji2_runtime.dds_rclpy.service_types import service_type_hash, wire_class

#: rmw_qos_profile_services_default
_DEPTH = 10

#: a reply waits at most this long [s] for its client's reply reader to be matched
HOLD_S = 30.0

_log = logging.getLogger(__name__)


def _qos(user_data: str) -> Qos:
    return Qos(Policy.Reliability.Reliable(0), Policy.Durability.Volatile, Policy.History.KeepLast(_DEPTH),
               Policy.DataRepresentation(use_cdrv0_representation=True),
               Policy.Userdata(user_data.encode("ascii")))


def _client_id(endpoint: Any) -> str | None:
    """The ``clientid`` in a discovered endpoint's USER_DATA (None: the endpoint is gone or has none)."""
    if endpoint is None:
        return None
    try:
        user_data = endpoint.qos[Policy.Userdata].data.decode("ascii", "replace")
    except (KeyError, AttributeError):
        return None
    fields = dict(item.split("=", 1) for item in user_data.split(";") if "=" in item)
    return fields.get("clientid")


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
        #: replies waiting for their client's reply reader: (client id, deadline [monotonic s], reply)
        self._held: list[tuple[str, float, Any]] = []
        self.dropped = 0

    def take(self, max_samples: int) -> list[Any]:
        """Up to ``max_samples`` pending requests (header and body; ``sample_info`` says who sent each)."""
        if self._reader is None:
            return []
        return [r for r in self._reader.take(N=max_samples) if isinstance(r, self._request_type)]

    def answer(self, request: Any) -> None:
        """Run the handler on one request and send the reply with the request's header, or hold it until the
        client's reply reader is matched (module docstring)."""
        if self._writer is None:
            return
        body = self._handler(request.body, self._response_body())
        reply = self._reply_type(client_guid=request.client_guid, sequence_number=request.sequence_number,
                                 body=body)
        info = getattr(request, "sample_info", None)
        client = None if info is None else _client_id(self._reader.get_matched_publication_data(
            info.publication_handle))
        if client is None or client in self._matched_clients():
            self._writer.write(reply)  # a client without an id cannot be checked: as before
            return
        self._held.append((client, time.monotonic() + HOLD_S, reply))

    @property
    def held(self) -> int:
        """Replies waiting for their client's reply reader."""
        return len(self._held)

    def send_held(self) -> None:
        """Send the held replies whose client's reply reader is now matched; drop those whose client's request
        writer is gone or whose time ran out."""
        if not self._held or self._writer is None:
            return
        matched, requesting = self._matched_clients(), self._requesting_clients()
        now, kept = time.monotonic(), []
        for client, deadline, reply in self._held:
            if client in matched:
                self._writer.write(reply)
            elif client in requesting and now < deadline:
                kept.append((client, deadline, reply))
            else:
                self.dropped += 1
                _log.warning("%s: reply dropped, its client %s %s", self.service_name, client,
                             "waited too long for its reply reader" if client in requesting else "went away")
        self._held = kept

    def _matched_clients(self) -> set[str]:
        """The client ids of the reply readers the reply writer has matched."""
        ids = (_client_id(self._writer.get_matched_subscription_data(handle))
               for handle in self._writer.get_matched_subscriptions())
        return {client for client in ids if client is not None}

    def _requesting_clients(self) -> set[str]:
        """The client ids of the request writers the request reader has matched."""
        ids = (_client_id(self._reader.get_matched_publication_data(handle))
               for handle in self._reader.get_matched_publications())
        return {client for client in ids if client is not None}

    def destroy(self) -> None:
        reader, writer, self._reader, self._writer = self._reader, self._writer, None, None
        for entity in (reader, writer):
            if entity is not None:
                entity.__del__()
