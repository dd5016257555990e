"""CCSDS Unsegmented Time Code (CUC, CCSDS 301.0-B-4): 4 coarse octets [s], 3 fine octets [2**-24 s].

spacepackets 0.32 implements the CDS time code only, so the CUC fields are written here, with
integer arithmetic on nanoseconds (exact; a time maps to the nearest fine count, so a stamp comes
back within half the resolution, 2**-25 s = 30 ns). Onboard time is counted from the onboard
clock's zero (the agency-defined epoch of the P-field); :mod:`.time_correlation` maps it to the
contract's time.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from taiji2_runtime.packets.definition import CUC_FINE_OCTETS, CUC_PFIELD

__all__ = ["CucError", "cuc_decode_ns", "cuc_encode", "cuc_encode_ns", "cuc_pack", "cuc_unpack_ns"]

_NS = 1_000_000_000
_FINE_BITS = 8 * CUC_FINE_OCTETS
_COARSE_MAX = 2**32 - 1


class CucError(ValueError):
    """A time that the CUC format cannot carry (negative, or beyond 2**32 s from the epoch)."""


def cuc_encode_ns(onboard_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Coarse and fine counts of onboard times [ns since the onboard epoch] (vectorised, exact).

    Raises
    ------
    CucError
        If a time is negative or at or beyond 2**32 s.
    """
    ns = np.asarray(onboard_ns, dtype=np.int64)
    if ns.size:
        _check_range(int(ns.min()), int(ns.max()))
    coarse, fine = _encode(ns)
    return coarse.astype(np.int64), fine.astype(np.int64)


def _check_range(first_ns: int, last_ns: int) -> None:
    if first_ns < 0 or last_ns // _NS > _COARSE_MAX:
        raise CucError(f"onboard time {first_ns / 1e9:g}..{last_ns / 1e9:g} s is outside the CUC range "
                       f"0..2**32 s of the onboard epoch (set the time correlation's offset)")


def _encode(ns: Any) -> tuple[Any, Any]:
    """Coarse and fine counts of ns: int64 arrays or Python ints alike (exact in both)."""
    coarse, rem = divmod(ns, _NS)
    fine = ((rem << _FINE_BITS) + _NS // 2) // _NS  # nearest count; rem < 1e9 so rem << 24 < 2**54
    carry = fine >> _FINE_BITS
    return coarse + carry, fine & ((1 << _FINE_BITS) - 1)


def cuc_decode_ns(coarse: np.ndarray, fine: np.ndarray) -> np.ndarray:
    """Onboard times [ns, int64, nearest] of coarse and fine counts (vectorised, exact)."""
    return _decode(np.asarray(coarse, dtype=np.int64), np.asarray(fine, dtype=np.int64))


def _decode(coarse: Any, fine: Any) -> Any:
    """Nearest ns of coarse and fine counts: int64 arrays or Python ints alike (exact in both: < 2**63)."""
    return coarse * _NS + ((fine * _NS + (1 << (_FINE_BITS - 1))) >> _FINE_BITS)


def cuc_encode(onboard_ns: int) -> tuple[int, int]:
    """Coarse and fine counts of one onboard time [ns] (Python integers: the onboard encodes every packet,
    and numpy's per-call cost exceeds this arithmetic; the same counts as :func:`cuc_encode_ns`)."""
    ns = int(onboard_ns)
    _check_range(ns, ns)
    return _encode(ns)


def cuc_pack(onboard_ns: int) -> bytes:
    """The 8-octet CUC field with its P-field (0x2F) of one onboard time [ns]."""
    coarse, fine = cuc_encode(onboard_ns)
    return bytes([CUC_PFIELD]) + coarse.to_bytes(4, "big") + fine.to_bytes(CUC_FINE_OCTETS, "big")


def cuc_unpack_ns(field: bytes) -> int:
    """Onboard time [ns] of an 8-octet CUC field with P-field.

    Raises
    ------
    CucError
        If the P-field is not 0x2F or the field is short.
    """
    if len(field) < 8 or field[0] != CUC_PFIELD:
        raise CucError(f"not a CUC time field with P-field 0x{CUC_PFIELD:02X}: {bytes(field[:8]).hex()}")
    # Python integers: one packet's time without numpy's per-call cost (the ground decodes every packet)
    return _decode(int.from_bytes(field[1:5], "big"), int.from_bytes(field[5:8], "big"))
