"""Read a truncated MCAP file up to the damage: its complete records, with a new end of file.

A recording cut short (a full disk, a killed recorder, a copy interrupted) loses the MCAP footer and the
summary with its index, so a reader refuses the whole file ("File end magic is invalid"), although every
chunk written before the cut is intact. MCAP's records are self-delimiting (opcode, 8-octet length,
content; MCAP spec, "Records"), so the complete ones are found by following the lengths from the start.
:func:`repaired_copy` writes them to a new file and ends it with a Data End record, a Footer without a
summary (``summary_start = 0``: a reader then scans the records) and the magic, which any MCAP reader opens.
Nothing is guessed: a record cut by the end of the file is dropped whole, and the note says how much was
recovered.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

__all__ = ["MCAP_MAGIC", "McapRepair", "complete_records_end", "repaired_copy"]

MCAP_MAGIC = b"\x89MCAP0\r\n"
_DATA_END, _FOOTER = 0x0F, 0x02
#: opcodes after which the data section is over (Data End, Footer, and the summary's records)
_END_OF_DATA = {_DATA_END, _FOOTER, 0x08, 0x0A, 0x0B, 0x0D, 0x0E}


@dataclass(frozen=True)
class McapRepair:
    """What :func:`repaired_copy` kept of a truncated MCAP file."""

    path: Path
    original_octets: int
    kept_octets: int
    records: int

    def note(self, source: Path) -> str:
        """One line for the user: what was recovered and what was lost."""
        lost = self.original_octets - self.kept_octets
        return (f"{source}: truncated MCAP (no footer): read its {self.records} complete records, "
                f"{self.kept_octets} of {self.original_octets} octets; the last {lost} octets (a record cut "
                "short) are lost")


def complete_records_end(data: bytes) -> tuple[int, int]:
    """The offset where the last complete data record of ``data`` (an MCAP file) ends, and the record count.

    Raises
    ------
    ValueError
        ``data`` does not start with the MCAP magic.
    """
    if not data.startswith(MCAP_MAGIC):
        raise ValueError("not an MCAP file (no magic at its start)")
    offset, records, size = len(MCAP_MAGIC), 0, len(data)
    while offset + 9 <= size:
        opcode = data[offset]
        (length,) = struct.unpack_from("<Q", data, offset + 1)
        end = offset + 9 + length
        if end > size or opcode in _END_OF_DATA:
            break
        offset, records = end, records + 1
    return offset, records


def repaired_copy(source: Path, out_dir: Path) -> McapRepair:
    """Write the complete records of the MCAP file ``source`` to ``out_dir/<name>``, properly ended.

    The new file holds the records up to :func:`complete_records_end`, then a Data End record (CRC 0: not
    computed), a Footer with no summary and the magic.
    """
    data = source.read_bytes()
    end, records = complete_records_end(data)
    target = out_dir / source.name
    data_end = bytes([_DATA_END]) + struct.pack("<Q", 4) + struct.pack("<I", 0)
    footer = bytes([_FOOTER]) + struct.pack("<Q", 20) + struct.pack("<QQI", 0, 0, 0)
    target.write_bytes(data[:end] + data_end + footer + MCAP_MAGIC)
    return McapRepair(target, len(data), end, records)
