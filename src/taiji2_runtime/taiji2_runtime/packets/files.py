"""Packet files and directories: recognised by content, read whole, decoded, written.

A *packet file* is a file whose first octets are a sound CCSDS space packet (plausible primary
header, version 0, unsegmented, whose packet passes its CRC-16-CCITT); a *packet directory* is a
directory without ``metadata.yaml`` (not a bag) whose regular files, other than ``*.yaml``, are
packet files, read in name order as one stream per APID. A directory's ``time_correlation.yaml``
(:mod:`.time_correlation`) is its time correlation unless one is given.
"""

from __future__ import annotations

import os
from pathlib import Path

from taiji2_runtime.packets.bulk_decode import DecodedPackets, decode_packet_buffers
from taiji2_runtime.packets.time_correlation import TimeCorrelation, load_time_correlation
from taiji2_runtime.packets.walk import starts_with_sound_packet

__all__ = ["PacketFileError", "is_packet_file", "is_packet_path", "packet_files", "read_packets", "write_packets"]

_PROBE_OCTETS = 65536 + 7
CORRELATION_FILE = "time_correlation.yaml"


class PacketFileError(ValueError):
    """A packet file or directory that cannot be read; ``str()`` names the path and the problem."""

    def __init__(self, path: str | Path, problem: str) -> None:
        self.path = Path(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


def is_packet_file(path: str | Path) -> bool:
    """True when ``path`` is a regular file that starts with a sound space packet."""
    path = Path(path)
    try:
        if not path.is_file():
            return False
        with path.open("rb") as handle:
            head = handle.read(_PROBE_OCTETS)
    except OSError:
        return False
    return starts_with_sound_packet(head)


def packet_files(path: str | Path) -> list[Path]:
    """The packet files of a packet file or directory (empty when it is neither)."""
    path = Path(path)
    if path.is_file():
        return [path] if is_packet_file(path) else []
    if not path.is_dir() or (path / "metadata.yaml").exists():
        return []
    files = sorted(p for p in path.iterdir() if p.is_file() and p.suffix not in (".yaml", ".yml")
                   and not p.name.startswith("."))
    if not files or not all(is_packet_file(p) for p in files):
        return []
    return files


def is_packet_path(path: str | Path) -> bool:
    """True for a packet file or a packet directory (see the module docstring)."""
    return bool(packet_files(path))


def read_packets(path: str | Path, correlation: TimeCorrelation | None = None, *,
                 telecommands: bool = True) -> DecodedPackets:
    """Decode a packet file or directory.

    Parameters
    ----------
    path : str or pathlib.Path
    correlation : TimeCorrelation, optional
        Default: the directory's ``time_correlation.yaml`` if any, else the identity.
    telecommands : bool
        Decode torque telecommands too.

    Raises
    ------
    PacketFileError
        One line naming the path and the problem (not a packet file, unreadable, nothing sound).
    """
    path = Path(path)
    files = packet_files(path)
    if not files:
        if not path.exists():
            raise PacketFileError(path, "no such file or directory")
        raise PacketFileError(path, "not a CCSDS packet file or directory (it does not start with a sound "
                                    "space packet)")
    if correlation is None:
        sidecar = (path if path.is_dir() else path.parent) / CORRELATION_FILE
        correlation = load_time_correlation(sidecar) if path.is_dir() and sidecar.exists() else TimeCorrelation()
    buffers = []
    for file in files:
        try:
            buffers.append((str(file), file.read_bytes()))
        except OSError as exc:
            raise PacketFileError(file, f"cannot read ({exc.strerror or exc})") from None
    decoded = decode_packet_buffers(buffers, correlation, telecommands=telecommands)
    if not decoded.streams and decoded.telecommands is None:
        raise PacketFileError(path, "no sound packet of a known APID (" + "; ".join(decoded.report.lines()[1:])
                              + ")")
    return decoded


def write_packets(path: str | Path, octets: bytes) -> None:
    """Write a packet file atomically (a temporary file, then a rename).

    Raises
    ------
    PacketFileError
        If ``path`` exists or cannot be written.
    """
    path = Path(path)
    if path.exists():
        raise PacketFileError(path, "already exists; choose another output or remove it")
    temporary = path.with_name(f".{path.name}.partial")
    try:
        with temporary.open("wb") as handle:
            handle.write(octets)
            handle.flush()
            os.fsync(handle.fileno())
        temporary.replace(path)
    except OSError as exc:
        temporary.unlink(missing_ok=True)
        raise PacketFileError(path, f"cannot write ({exc.strerror or exc})") from None
