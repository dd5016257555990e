"""First-order linear recursions ``y_k = lam y_{k-1} + x_k`` evaluated in bulk (numpy only).

Used by the bulk paths of the two-stage filter: each mode of a steady-state filter is one such
recursion. numpy only, so that importing the estimators does not import scipy.signal (whose import
costs more than a whole calibration's filtering).
"""

from __future__ import annotations

import numpy as np

__all__ = ["first_order_recursion"]

#: largest |lambda|^-j inside one block of :func:`first_order_recursion` (bounds the rounding growth)
_BLOCK_GROWTH = 100.0


def _doubling_recursion(mu: complex, drive: np.ndarray) -> np.ndarray:
    """``y_k = mu y_{k-1} + x_k`` (``y_-1 = 0``) by recursive doubling (log2 passes; |mu| small)."""
    y = drive.copy()
    shift, power = 1, mu
    # after the pass with shift s, y_k = sum_{i < 2s} mu^i x_{k-i}: stop once mu^s is below rounding
    while shift < y.shape[0] and abs(power) > 1e-18:
        y[shift:] = y[shift:] + power * y[:-shift]
        shift, power = 2 * shift, power * power
    return y


def _block_scales(lam: complex, block: int) -> tuple[np.ndarray, np.ndarray]:
    """``lam^-j`` and ``lam^(j+1)`` for j = 0..block-1 (cached: a filter has few modes)."""
    key = (complex(lam), block)
    cached = _SCALES.get(key)
    if cached is None:
        powers = np.arange(block, dtype=np.float64)
        cached = (lam ** -powers, lam ** (powers + 1.0))
        if len(_SCALES) > 64:
            _SCALES.clear()
        _SCALES[key] = cached
    return cached


_SCALES: dict[tuple[complex, int], tuple[np.ndarray, np.ndarray]] = {}


def first_order_recursion(lam: complex, drive: np.ndarray, initial: np.ndarray,
                          out: np.ndarray | None = None) -> np.ndarray:
    """``y_k = lam y_{k-1} + x_k`` for k = 0..L-1 with ``y_-1 = initial``, in bulk.

    The same as ``scipy.signal.lfilter([1], [1, -lam], x, axis=0, zi=lam * initial)``, evaluated
    without a Python loop over samples: the record is cut into blocks of B samples with
    ``|lam|^-B <= 100``; inside a block ``y_{s+j} = lam^(j+1) (y_{s-1} + sum_{i<=j} lam^-(i+1) x_{s+i})``
    (a scaled cumulative sum), and the values carried from block to block obey the same recursion
    with ``lam^B`` (small), solved by recursive doubling. Rounding grows by at most ~100 eps.

    Parameters
    ----------
    lam : complex or float
        Pole, ``|lam| <= 1``.
    drive : numpy.ndarray
        (L, ...) input x.
    initial : numpy.ndarray
        (...) state before the first sample.
    out : numpy.ndarray, optional
        (L, ...) array to write y into.

    Returns
    -------
    numpy.ndarray
        (L, ...) y, complex if ``lam`` or the input is.
    """
    length = drive.shape[0]
    dtype = np.result_type(drive.dtype, np.asarray(initial).dtype, type(lam))
    if length == 0:
        return np.zeros(drive.shape, dtype=dtype)
    magnitude = abs(lam)
    if magnitude == 0.0:
        return drive.astype(dtype, copy=True)
    decay = -np.log(magnitude) if magnitude < 1.0 else 0.0
    longest = length if decay == 0.0 else int(max(1, min(length, np.log(_BLOCK_GROWTH) // decay)))
    # blocks of equal length, none longer than the bound: no padding beyond the last few samples
    n_blocks = -(-length // longest)
    block = -(-length // n_blocks)
    tail = drive.shape[1:]
    inverse, forward = _block_scales(lam, block)
    shape = (1, block) + (1,) * len(tail)
    work = np.empty((n_blocks, block, *tail), dtype=dtype)
    flat = work.reshape(n_blocks * block, *tail)
    # z = lam^-(j+1) x (scaled input), then its running sum inside each block
    np.multiply(drive, np.tile(inverse / lam, n_blocks)[:length].reshape((length,) + (1,) * len(tail)),
                out=flat[:length])
    flat[length:] = 0.0
    np.cumsum(work, axis=1, out=work)
    # carried state c_b = y at the end of block b-1: c_b = lam^B c_{b-1} + lam^B * running sum_{b-1, last}
    carry_drive = np.empty((n_blocks, *tail), dtype=dtype)
    carry_drive[0] = np.asarray(initial, dtype=dtype)
    carry_drive[1:] = forward[-1] * work[:-1, -1]
    carry = _doubling_recursion(lam ** block, carry_drive)
    # y = lam^(j+1) (c_b + running sum)
    work += carry[:, None]
    work *= forward.reshape(shape)
    if out is None:
        return flat[:length]
    out[...] = flat[:length]
    return out
