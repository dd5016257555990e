"""What a packet stream held, per APID: the counts ``taiji2 bag info`` prints and the loaders report."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Any

from taiji2_runtime.packets.definition import STREAM_BY_APID, TC_APID

__all__ = ["APID_COUNTS", "PacketReport"]

#: per-APID counters, in print order
APID_COUNTS = ("packets", "kept", "crc_error", "truncated", "wrong_length", "bad_time_field", "bad_header",
               "wrong_service", "duplicate", "out_of_order", "sequence_gap", "wraps")


def _apid_name(apid: int) -> str:
    if apid in STREAM_BY_APID:
        return f"0x{apid:03X} {STREAM_BY_APID[apid].name}"
    if apid == TC_APID:
        return f"0x{apid:03X} telecommands"
    return f"0x{apid:03X}" if apid >= 0 else "(unreadable)"


@dataclass
class PacketReport:
    """Counts of one packet file or directory.

    Attributes
    ----------
    sources : list of str
        The files read, in order.
    octets : int
        Octets read.
    per_apid : dict
        ``{apid: Counter}`` with the keys of :data:`APID_COUNTS`: ``packets`` (sound packets),
        ``kept`` (samples after deduplication), ``crc_error`` (dropped; APID as read),
        ``truncated`` (final packet cut short), ``wrong_length`` / ``bad_time_field`` (dropped),
        ``bad_header`` / ``wrong_service`` (telecommands: not a PUS-C TC, not the torque service; dropped),
        ``duplicate`` (copies left out), ``out_of_order`` (kept, reordered), ``sequence_gap``
        (counts never received soundly: the samples become missing), ``wraps`` (14-bit wraps).
    unknown_apid : collections.Counter
        Sound packets of APIDs the definition does not know (skipped), per APID.
    idle : int
        Idle packets (APID 0x7FF, skipped).
    corrupt_header : int
        Packets whose primary header was unreadable (the stream was resynchronised).
    skipped_octets : int
        Octets skipped while resynchronising.
    """

    sources: list[str] = field(default_factory=list)
    octets: int = 0
    per_apid: dict[int, Counter] = field(default_factory=dict)
    unknown_apid: Counter = field(default_factory=Counter)
    idle: int = 0
    corrupt_header: int = 0
    skipped_octets: int = 0

    def apid(self, apid: int) -> Counter:
        """The counters of ``apid`` (created empty)."""
        return self.per_apid.setdefault(apid, Counter())

    def defects(self) -> dict[str, int]:
        """Total per kind of defect (over all APIDs and the file-level counts), zeros left out."""
        total: Counter = Counter()
        for counts in self.per_apid.values():
            for key in APID_COUNTS[2:-1]:
                total[key] += counts.get(key, 0)
        total["unknown_apid"] = sum(self.unknown_apid.values())
        total["idle"] = self.idle
        total["corrupt_header"] = self.corrupt_header
        return {k: int(v) for k, v in total.items() if v}

    def lines(self) -> list[str]:
        """Human-readable summary, one line per APID."""
        out = [f"packets: {len(self.sources)} file(s), {self.octets} octets"]
        for apid in sorted(self.per_apid):
            counts = self.per_apid[apid]
            parts = [f"{k} {counts[k]}" for k in APID_COUNTS if counts.get(k)]
            out.append(f"  APID {_apid_name(apid)}: " + (", ".join(parts) or "nothing sound"))
        if self.unknown_apid:
            out.append("  unknown APIDs (skipped): " + ", ".join(f"0x{a:03X} {n}" for a, n in
                                                               sorted(self.unknown_apid.items())))
        extra = [f"{name} {value}" for name, value in (("idle", self.idle), ("corrupt_header", self.corrupt_header),
                                                        ("skipped_octets", self.skipped_octets)) if value]
        if extra:
            out.append("  " + ", ".join(extra))
        return out

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        return {"sources": list(self.sources), "octets": self.octets,
                "apids": {_apid_name(a): {k: int(c.get(k, 0)) for k in APID_COUNTS} for a, c in
                          sorted(self.per_apid.items())},
                "unknown_apid": {f"0x{a:03X}": int(n) for a, n in sorted(self.unknown_apid.items())},
                "idle": self.idle, "corrupt_header": self.corrupt_header, "skipped_octets": self.skipped_octets,
                "defects": self.defects()}
