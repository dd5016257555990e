"""Order one APID's packets by their 14-bit sequence count: unwrap, keep each count once, count gaps.

Sequence counts are unwrapped from their differences in arrival order, each taken in [-8192, 8192)
(so reordering and duplication within half the counter's range are seen as such); where the onboard
times say that more than 8192 counts elapsed (a long loss), the difference is moved by whole
wraps (16384) to agree with them. A count received twice is kept once (the first sound copy), and
the packets come out in count order (= time order).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from taiji2_runtime.packets.packetize import SEQ_MODULO

__all__ = ["SequenceOrder", "order_by_sequence"]

_HALF = SEQ_MODULO // 2


@dataclass(frozen=True)
class SequenceOrder:
    """Result of :func:`order_by_sequence`.

    Attributes
    ----------
    keep : numpy.ndarray
        Indices (into the arrival order) of the packets kept, in sequence order.
    index : numpy.ndarray
        Unwrapped sequence index of each kept packet (from 0).
    duplicate, out_of_order, sequence_gap, wraps : int
        Copies left out; packets that arrived after one with a later count; counts never received
        soundly (lost, or dropped for a defect); times the 14-bit counter wrapped.
    """

    keep: np.ndarray
    index: np.ndarray
    duplicate: int
    out_of_order: int
    sequence_gap: int
    wraps: int


def order_by_sequence(seq_count: np.ndarray, onboard_ns: np.ndarray) -> SequenceOrder:
    """Unwrap, deduplicate and order one APID's packets (arrival order in, sequence order out)."""
    seq = np.asarray(seq_count, dtype=np.int64)
    n = seq.shape[0]
    if n == 0:
        return SequenceOrder(np.empty(0, np.int64), np.empty(0, np.int64), 0, 0, 0, 0)
    step = (np.diff(seq) + _HALF) % SEQ_MODULO - _HALF
    dt = np.diff(np.asarray(onboard_ns, dtype=np.int64)).astype(np.float64)
    single = dt[(step == 1) & (dt > 0)]
    if single.size:  # a loss longer than half the counter: the onboard times tell how many wraps
        expected = dt / float(np.median(single))
        far = np.abs(expected - step) > _HALF
        if far.any():
            step = step + np.where(far, np.rint((expected - step) / SEQ_MODULO).astype(np.int64) * SEQ_MODULO, 0)
    index = np.concatenate([[0], np.cumsum(step)])
    late = int(np.count_nonzero(index[1:] < np.maximum.accumulate(index)[:-1]))
    order = np.lexsort((np.arange(n), index))
    ordered = index[order]
    first = np.ones(n, dtype=bool)
    first[1:] = ordered[1:] != ordered[:-1]
    keep = order[first]
    kept_index = ordered[first]
    origin = kept_index[0]
    span = int(kept_index[-1] - origin) + 1
    wraps = int((seq[keep[0]] + kept_index[-1] - origin) // SEQ_MODULO)
    return SequenceOrder(keep, kept_index - origin, n - keep.shape[0], late, span - keep.shape[0], wraps)
