"""Commanding through Yamcs: the planner's time-tagged tables (TC[11,4]) as commands of the XTCE database, and
what Yamcs's command history says of them.

* :func:`insert_activities_arguments`: the arguments of the ``insert_activities`` MetaCommand that make Yamcs
  encode the application data of one of the planner's TC[11,4] octet for octet (the one encoder stays
  :func:`taiji2_runtime.packets.scheduling.encode_insert_activities`; this only slices its output);
* :func:`table_digest`: the key that joins a table as planned and as Yamcs sent it (SHA-256 of the
  application data: Yamcs's postprocessor sets the sequence count, the length and the CRC, never the data);
* :class:`YamcsCommander`: issues the tables in order over one command connection and follows each one's
  history (Queued, Released, Sent, then the onboard Acceptance and Execution stages of the XTCE verifiers).
"""

from __future__ import annotations

import hashlib
import threading
from typing import Any

from taiji2_ground_pkg.mcs.errors import GroundError
from taiji2_ground_pkg.mcs.xtce import COMMAND_STAGES, SYSTEM_NAME, VERIFIER_STAGES
from taiji2_runtime.packets.definition import TC_APID

__all__ = ["COMMAND", "YamcsCommander", "application_data", "insert_activities_arguments", "stage_counts",
           "table_digest"]

#: the MetaCommand the tables are issued as
COMMAND = f"/{SYSTEM_NAME}/insert_activities"
_PRIMARY, _SECONDARY, _CRC = 6, 5, 2  # CCSDS primary header, PUS-C TC secondary header, CRC [octets]
_CUC_OCTETS = 8  # an activity's release time: P-field, 4 coarse, 3 fine
_VERIFIED = {name for name, _ in VERIFIER_STAGES}
#: the command history's acknowledgment names: Yamcs's stages, then the verifiers'
_ACK_PREFIX = {False: "Acknowledge_", True: "Verifier_"}


def application_data(packet: bytes) -> bytes:
    """The application data of a PUS-C TC (between the secondary header and the CRC)."""
    return bytes(packet[_PRIMARY + _SECONDARY:-_CRC])


def table_digest(packet: bytes) -> str:
    """SHA-256 (hex) of a TC's application data."""
    return hashlib.sha256(application_data(packet)).hexdigest()


def insert_activities_arguments(packet: bytes) -> dict[str, Any]:
    """The ``insert_activities`` arguments of a TC[11,4] of the planner (N, then each activity's release time
    as CUC P-field, coarse and fine, and its request: the whole TC[130,1], binary)."""
    data = application_data(packet)
    n = int.from_bytes(data[:2], "big")
    size = (len(data) - 2) // n if n else 0
    if n == 0 or 2 + n * size != len(data) or size <= _CUC_OCTETS:
        raise ValueError(f"not a TC[11,4] of whole activities: {len(data)} octets of application data, N = {n}")
    activities = []
    for k in range(n):
        a = data[2 + k * size:2 + (k + 1) * size]
        activities.append({"release_cuc_pfield": a[0], "release_cuc_coarse": int.from_bytes(a[1:5], "big"),
                           "release_cuc_fine": int.from_bytes(a[5:8], "big"), "request": bytes(a[_CUC_OCTETS:])})
    return {"apid": TC_APID, "N": n, "activities": activities}


class YamcsCommander:
    """Issues tables to the Yamcs instance at ``url`` (``yamcs://HOST:PORT/INSTANCE``) and reads their history.

    Thread-safe: :meth:`issue` may run in a thread of its own while :meth:`history` is read from another.
    """

    def __init__(self, url: str, processor: str = "realtime") -> None:
        from taiji2_ground_pkg.mcs.yamcs_api import connect, parse_yamcs_url

        self.url = url
        self._address = parse_yamcs_url(url)  # GroundError naming the address
        self._client = connect(self._address.server)
        self._processor = self._client.get_processor(self._address.instance, processor)
        self._connection: Any = None
        self._commands: list[Any] = []
        self._lock = threading.Lock()

    def wait_for_link(self, link: str, *, stop: threading.Event, poll_s: float = 0.5) -> bool:
        """Wait until Yamcs's ``link`` is connected (status ``OK``; a TC sent before would fail), or ``stop``."""
        while not stop.is_set():
            info = next((lk for lk in self._client.list_links(self._address.instance) if lk.name == link), None)
            if info is None:
                raise GroundError(f"{self.url}: the instance has no link {link!r}")
            if str(info.status) == "OK":
                return True
            stop.wait(poll_s)
        return False

    def issue(self, packets: list[bytes], comments: list[str], stream: str = "tc_realtime") -> None:
        """Issue each TC[11,4] of ``packets`` (in order) with its comment (shown in the command history) on the
        command ``stream`` (``tc_realtime``: the ground-station link; ``tc_frames``: Yamcs's SDLS frame link)."""
        if self._connection is None:
            self._connection = self._processor.create_command_connection()
        for packet, comment in zip(packets, comments, strict=True):
            command = self._connection.issue(COMMAND, args=insert_activities_arguments(packet), comment=comment,
                                             stream=None if stream == "tc_realtime" else stream)
            with self._lock:
                self._commands.append(command)

    def history(self) -> list[dict[str, Any]]:
        """Per issued table, in order: ``seq_count`` (the CCSDS count Yamcs gave it; None before it was sent),
        each stage's status (``Queued``, ``Released``, ``Sent``, ``Acceptance``, ``Execution``: OK, NOK,
        PENDING, TIMEOUT or None) and ``message`` (a failed stage's reason)."""
        with self._lock:
            commands = list(self._commands)
        out = []
        for command in commands:
            attributes = dict(command.attributes)
            acks = dict(command.acknowledgments)
            entry: dict[str, Any] = {"id": command.id, "seq_count": attributes.get("ccsds-seqcount")}
            for stage in COMMAND_STAGES:
                ack = acks.get(f"{_ACK_PREFIX[stage in _VERIFIED]}{stage}")
                entry[stage] = getattr(ack, "status", None)
            entry["message"] = next((a.message for a in acks.values() if getattr(a, "message", None)), None)
            out.append(entry)
        return out

    def close(self) -> None:
        if self._connection is not None:
            self._connection.cancel()  # the command connection is a WebSocket subscription
        self._client.close()


def stage_counts(history: list[dict[str, Any]]) -> dict[str, Any]:
    """Of a command history (:meth:`YamcsCommander.history` or ``yamcs_api.command_history``): the commands,
    per stage those that passed it (OK), and the failed ones (a stage NOK or timed out) with Yamcs's message."""
    return {"issued": len(history), **{s: sum(h[s] == "OK" for h in history) for s in COMMAND_STAGES},
            "failed": [{"seq_count": h["seq_count"], "message": h["message"] or "failed"} for h in history
                       if any(h[s] in ("NOK", "TIMEOUT") for s in COMMAND_STAGES)]}
