"""Damage a packet stream the way a real downlink does, and say exactly what was done."""

from __future__ import annotations

from collections import Counter

import numpy as np

from taiji2_runtime.packets.walk import walk_packets


def corrupt_stream(octets: bytes, seed: int = 3, *, flip: float = 0.01, drop: float = 0.005, duplicate: float = 0.005,
                   reorder_block: int = 200) -> tuple[bytes, Counter]:
    """A copy of ``octets`` with packets bit-flipped (one bit each), dropped, duplicated (the copy
    right after the original) and one block of ``reorder_block`` packets reversed; returns it and
    the counts by kind (each damaged packet has one defect only)."""
    rng = np.random.default_rng(seed)
    walk = walk_packets(octets)
    n = walk.starts.shape[0]
    packets = [octets[s:e] for s, e in zip(walk.starts.tolist(), walk.ends.tolist(), strict=True)]
    kind = np.zeros(n, dtype=np.int8)  # 0 clean, 1 flip, 2 drop, 3 duplicate
    block_start = int(rng.integers(n // 4, n // 2))
    free = np.ones(n, dtype=bool)
    free[block_start:block_start + reorder_block] = False
    free[[0, n - 1]] = False
    chosen = rng.permutation(np.flatnonzero(free))
    n_flip, n_drop, n_dup = round(flip * n), round(drop * n), round(duplicate * n)
    kind[chosen[:n_flip]] = 1
    kind[chosen[n_flip:n_flip + n_drop]] = 2
    kind[chosen[n_flip + n_drop:n_flip + n_drop + n_dup]] = 3
    out: list[bytes] = []
    for k in range(n):
        if block_start <= k < block_start + reorder_block:
            if k == block_start:
                out.extend(reversed(packets[block_start:block_start + reorder_block]))
            continue
        packet = packets[k]
        if kind[k] == 1:
            damaged = bytearray(packet)
            bit = int(rng.integers(0, 8 * len(packet)))
            damaged[bit // 8] ^= 1 << (bit % 8)
            out.append(bytes(damaged))
        elif kind[k] == 2:
            continue
        elif kind[k] == 3:
            out.extend([packet, packet])
        else:
            out.append(packet)
    return b"".join(out), Counter(flipped=n_flip, dropped=n_drop, duplicated=n_dup, reordered=reorder_block)
