"""The ground's SDLS frame signer from a key file (docs/security.md): one place for the planner (without Yamcs)
and the Yamcs ground station (with it), whichever hands the frames to the uplink."""

from __future__ import annotations

from taiji2_runtime.packets.sdls import FrameSigner
from taiji2_runtime.packets.sdls_keys import KeyFileError, key_file_warning, load_key_file

__all__ = ["frame_signer"]


def frame_signer(key_file: str, spi: int, first_sequence: int) -> tuple[FrameSigner | None, str, str]:
    """``(signer, problem, warning)``: the signer of ``key_file`` with ``spi`` (-1: its highest active SPI) from
    SDLS sequence number ``first_sequence``, or None and why not (no or unusable key file: nothing can be
    sent, as the spacecraft refuses frames without a valid MAC); ``warning`` a caution about the file (e.g.
    readable by others), or empty."""
    try:
        if not key_file:
            raise KeyFileError("no key_file")
        signer = FrameSigner(load_key_file(key_file), None if spi < 0 else spi, first_sequence)
    except (KeyFileError, ValueError) as exc:
        return None, f"telecommands not sent: {exc}", ""
    return signer, "", key_file_warning(key_file) or ""
