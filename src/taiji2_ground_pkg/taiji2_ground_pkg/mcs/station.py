"""The ground station front end that Yamcs's data link connects to: a TCP server that hands Yamcs the CCSDS
Space Packets the ground received, in reception order.

Yamcs's ``TcpTcTmDataLink`` is a TCP client (it connects to a ground station or an SLE provider and
retries while it cannot); this is the server side. Packets are queued and written by a thread of their
own, so a slow Yamcs never blocks the caller (a node's executor); while Yamcs is not connected (not yet,
or restarting) they wait in the queue, in order, and go out when it connects. Packets go out in batches of
up to ``BATCH`` (one system call each); a batch whose write fails is sent again, whole, on the next
connection (Yamcs reads packets by their length field, so a half packet would desynchronise it; the archive
keeps one copy of a packet per generation time and sequence number). TCP has no receipt: what was written
to a connection that Yamcs then closed without reading it is lost, so :attr:`sent_packets` counts what
was written, and whoever needs the count of what arrived asks Yamcs (its link's count;
``taiji2 experiment --ground`` compares the two).

Telecommands come the other way on the same connection: Yamcs's link writes each released command (a whole
CCSDS Space Packet, after its postprocessor) and a reader thread hands each, whole, to ``on_telecommand``
(a partial packet at a closed connection is dropped and counted: Yamcs marks the command as not sent).
"""

from __future__ import annotations

import collections
import contextlib
import socket
import threading
from collections.abc import Callable, Iterable

__all__ = ["BATCH", "StationFrontEnd"]

#: packets per write
BATCH = 512
_PRIMARY_HEADER_OCTETS = 6


class StationFrontEnd:
    """A TCP server on ``host:port`` for one Yamcs link at a time (module docstring).

    Parameters
    ----------
    port : int
        The port of the instance's ``ground-station`` link (``taiji2 ground serve --station-port``).
    host : str
        The address to listen on (localhost: the link is the ground's own).
    on_telecommand : callable, optional
        Called (from the reader thread) with each telecommand packet Yamcs sends; without it they are counted
        and dropped.
    """

    def __init__(self, port: int, host: str = "127.0.0.1",
                 on_telecommand: Callable[[bytes], None] | None = None) -> None:
        self._server = socket.create_server((host, int(port)), reuse_port=False)
        self._server.settimeout(0.5)
        self._queue: collections.deque[bytes] = collections.deque()
        self._ready = threading.Condition()
        self._closed = False
        self.sent_packets = 0
        self.connections = 0
        self.telecommands = 0
        self.partial_telecommands = 0
        self._on_telecommand = on_telecommand
        self._thread = threading.Thread(target=self._serve, name="yamcs-station", daemon=True)
        self._thread.start()

    @property
    def port(self) -> int:
        return self._server.getsockname()[1]

    def send(self, packets: Iterable[bytes]) -> None:
        """Queue ``packets`` (each one whole CCSDS Space Packet) for Yamcs, in order; returns at once."""
        with self._ready:
            self._queue.extend(bytes(p) for p in packets)
            self._ready.notify()

    def queued(self) -> int:
        """Packets not yet written to Yamcs."""
        with self._ready:
            return len(self._queue)

    def close(self) -> None:
        """Stop serving (what is still queued is not sent: say so with :meth:`queued` first)."""
        with self._ready:
            self._closed = True
            self._ready.notify()
        self._thread.join(timeout=5.0)
        self._server.close()

    def _serve(self) -> None:
        while not self._closed:
            try:
                connection, _ = self._server.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            self.connections += 1
            with connection:
                connection.settimeout(None)
                closed = threading.Event()
                reader = threading.Thread(target=self._read_telecommands, args=(connection, closed),
                                          name="yamcs-station-tc", daemon=True)
                reader.start()
                self._write_until_broken(connection, closed)
                with contextlib.suppress(OSError):
                    connection.shutdown(socket.SHUT_RDWR)  # ends the reader's recv
                reader.join(timeout=5.0)

    def _read_telecommands(self, connection: socket.socket, closed: threading.Event) -> None:
        """Whole packets (by the primary header's length field) from ``connection`` until it closes."""
        buffer = bytearray()
        while True:
            try:
                chunk = connection.recv(65536)
            except OSError:
                chunk = b""
            if not chunk:
                self.partial_telecommands += bool(buffer)
                closed.set()
                with self._ready:
                    self._ready.notify()  # the writer stops serving this connection and awaits the next
                return
            buffer += chunk
            while len(buffer) >= _PRIMARY_HEADER_OCTETS:
                size = _PRIMARY_HEADER_OCTETS + int.from_bytes(buffer[4:6], "big") + 1
                if len(buffer) < size:
                    break
                packet = bytes(buffer[:size])
                del buffer[:size]
                self.telecommands += 1
                if self._on_telecommand is not None:
                    self._on_telecommand(packet)

    def _write_until_broken(self, connection: socket.socket, closed: threading.Event) -> None:
        while True:
            with self._ready:
                while not self._queue and not self._closed and not closed.is_set():
                    self._ready.wait(0.5)
                if self._closed or closed.is_set():
                    return
                batch = [self._queue[i] for i in range(min(BATCH, len(self._queue)))]
            try:
                connection.sendall(b"".join(batch))
            except OSError:
                return  # Yamcs went away: the batch stays first in the queue for the next connection
            with self._ready:
                for _ in batch:
                    self._queue.popleft()
                self.sent_packets += len(batch)
