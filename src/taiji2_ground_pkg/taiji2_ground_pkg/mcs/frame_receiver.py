"""Where Yamcs's own SDLS-secured TC frames arrive at the ground station: its ``UdpTcFrameLink`` sends one
TC Transfer Frame per UDP datagram to ``127.0.0.1:port`` (:class:`~.yamcs_instance.SdlsFrameLink`).

:class:`FrameReceiver` takes each datagram in a thread of its own, opens the frame with the ground's key
table (the frame data are encrypted: authenticated encryption is Yamcs's only service) to read the
telecommand packet inside, and hands ``(frame, packet)`` to a callback: the frame goes to the uplink as Yamcs
made it, the packet says which table of the plan it carries. A datagram that is not an authentic frame of a
known SPI is counted and dropped. The ground's check leaves the onboard anti-replay state alone (it has its
own verifier, with the anti-replay of the spacecraft).
"""

from __future__ import annotations

import socket
import threading
from collections.abc import Callable

from taiji2_runtime.packets.sdls import FrameRefused, FrameVerifier
from taiji2_runtime.packets.sdls_keys import KeyTable
from taiji2_runtime.packets.tc_frame import MAX_FRAME_OCTETS

__all__ = ["FrameReceiver"]


class FrameReceiver:
    """A UDP receiver of Yamcs's TC frames on ``127.0.0.1:port`` (module docstring)."""

    def __init__(self, port: int, keys: KeyTable, on_frame: Callable[[bytes, bytes], None]) -> None:
        self._socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._socket.bind(("127.0.0.1", int(port)))
        self._socket.settimeout(0.5)
        self._keys = keys
        self._on_frame = on_frame
        self._closed = threading.Event()
        self.frames = 0
        self.refused: dict[str, int] = {}
        self._thread = threading.Thread(target=self._receive, name="yamcs-frames", daemon=True)
        self._thread.start()

    def _receive(self) -> None:
        while not self._closed.is_set():
            try:
                frame = self._socket.recv(MAX_FRAME_OCTETS + 1)
            except TimeoutError:
                continue
            except OSError:
                return
            # a verifier of its own per frame: the ground reads what is inside, the spacecraft judges freshness
            try:
                packet = FrameVerifier(self._keys, window=2**95).verify(frame)
            except FrameRefused as exc:
                self.refused[exc.reason] = self.refused.get(exc.reason, 0) + 1
                continue
            self.frames += 1
            self._on_frame(frame, packet)

    def close(self) -> None:
        self._closed.set()
        self._thread.join(timeout=5.0)
        self._socket.close()
