"""A ROS 2 service client over Cyclone DDS (the wire format of :mod:`service_types`).

Used by ``taiji2 param`` and the tests; it talks to any server on the domain, embedded or rclpy.
``send`` returns the request's sequence number and ``reply`` collects the answer without blocking,
so a caller can spin an executor in between; ``call`` blocks for the no-ROS command line.
"""

from __future__ import annotations

import itertools
import time
import uuid
from typing import Any

from cyclonedds.core import InstanceState, Policy, Qos, ReadCondition, SampleState, ViewState, WaitSet
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.util import duration

from taiji2_runtime.dds_rclpy.service import _DEPTH, _service_id
from taiji2_runtime.dds_rclpy.service_types import service_body_class, service_type_hash, wire_class

#: a request not answered within this long [s] is sent again (see :meth:`ServiceClient.call`)
_RESEND_S = 1.0
_POLL_S = 0.05


def _qos(user_data: str) -> Qos:
    return Qos(Policy.Reliability.Reliable(0), Policy.Durability.Volatile, Policy.History.KeepLast(_DEPTH),
               Policy.DataRepresentation(use_cdrv0_representation=True),
               Policy.Userdata(user_data.encode("ascii")))


class ServiceClient:
    """Calls service ``service_name`` of type ``srv`` (``pkg/srv/Name``)."""

    def __init__(self, context: Any, srv: str, service_name: str) -> None:
        participant = context.participant()
        self._participant = participant
        self.service_name = service_name
        self.request_class = service_body_class(srv, "Request")
        self._request_type = wire_class(srv, "Request")
        self._reply_type = wire_class(srv, "Response")
        client_id = uuid.uuid4().bytes
        # any 64-bit value unique to this client: the server echoes it, we keep only our replies
        self._client_guid = int.from_bytes(client_id[:8], "little")
        user = f"clientid={_service_id(client_id)};"
        self._writer = DataWriter(participant, context.topic(f"rq{service_name}Request", self._request_type),
                                  _qos(user + f"typehash={service_type_hash(srv, 'Request')};"))
        self._reader = DataReader(participant, context.topic(f"rr{service_name}Reply", self._reply_type),
                                  _qos(user + f"typehash={service_type_hash(srv, 'Response')};"))
        self._sequence = itertools.count(1)
        self._replies: dict[int, Any] = {}

    def service_is_ready(self) -> bool:
        """True once a server's request reader and reply writer are both matched."""
        return (self._writer.get_publication_matched_status().current_count > 0
                and self._reader.get_subscription_matched_status().current_count > 0)

    def send(self, request: Any) -> int:
        """Send a request body; returns its sequence number."""
        sequence = next(self._sequence)
        self._writer.write(self._request_type(client_guid=self._client_guid, sequence_number=sequence, body=request))
        return sequence

    def reply(self, sequence: int) -> Any | None:
        """The response body to request ``sequence`` if it has arrived (None otherwise)."""
        for sample in self._reader.take(N=64):
            if isinstance(sample, self._reply_type) and sample.client_guid == self._client_guid:
                self._replies[sample.sequence_number] = sample.body
        return self._replies.pop(sequence, None)

    def call(self, request: Any, timeout_s: float) -> Any:
        """Wait for the service, send ``request`` and wait for its response body.

        Raises
        ------
        TimeoutError
            If no server appears, or none answers, within ``timeout_s``.
        """
        deadline = time.monotonic() + timeout_s
        waitset = WaitSet(self._participant)
        waitset.attach(ReadCondition(self._reader, SampleState.NotRead | ViewState.Any | InstanceState.Any))
        while not self.service_is_ready():
            if time.monotonic() > deadline:
                raise TimeoutError(f"service {self.service_name} is not available (waited {timeout_s:g} s)")
            time.sleep(_POLL_S)  # discovery has no event to wait on here; poll the match counts
        # Re-sent every _RESEND_S until answered: discovery is not symmetric in time, and a reply the
        # server writes before its writer has matched this client's reader is lost. The services this
        # client calls (rcl_interfaces parameters) are idempotent, so a second request is harmless.
        sequences = [self.send(request)]
        sent_at = time.monotonic()
        while (response := next((r for r in map(self.reply, sequences) if r is not None), None)) is None:
            now = time.monotonic()
            remaining = deadline - now
            if remaining <= 0:
                raise TimeoutError(f"service {self.service_name} did not answer within {timeout_s:g} s")
            if now - sent_at >= _RESEND_S:
                sequences.append(self.send(request))
                sent_at = now
            waitset.wait(duration(seconds=min(remaining, _RESEND_S)))
        for sequence in sequences:  # answers to the repeated requests that arrived meanwhile
            self._replies.pop(sequence, None)
        return response
