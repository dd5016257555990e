"""The running attitude product ``q_{k+1} = q_0 r_0 r_1 ... r_k``, independent of how it is cut.

Quaternion products do not associate in floating point: a blocked (vectorised) scan that starts
where each call starts gives attitudes that depend, at 1e-15, on how the steps were cut into calls.
The node graph's simulator advances in chunks set by when commands arrive, so two runs of the same
seed differed in the last bits of the star-tracker quaternions. Here the association is fixed by
the *absolute* step index, whatever the calls:

* epochs of :data:`EPOCH_STEPS` steps (256), counted from step 0; each is cut into blocks of
  :data:`BLOCK_STEPS` (16);
* inside a block, the running product left to right: ``I_j = (r_b r_{b+1}) ... r_j`` (``I`` of the
  first step is that increment itself);
* the carry of block b inside its epoch: ``C_0 = 1``, ``C_1 = T_0``, ``C_b = C_{b-1} T_{b-1}``
  (``T`` a block's last ``I``);
* the attitude ``q = (E C_b) I_j``, with ``E`` the attitude at the start of the epoch (the last
  attitude of the one before).

:meth:`AttitudeScan.extend` computes this either step by step (plain floats, for the few steps a
streaming call brings) or vectorised over whole epochs (numpy, for a batch), with the same products
in the same order, so the two give the same bits (tested) and a run gives the same attitudes
whether it is simulated at once or in any chunks.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from taiji2_model.frames import _hamilton_product

__all__ = ["BLOCK_STEPS", "EPOCH_STEPS", "AttitudeScan"]

#: Steps per block (running product left to right inside it).
BLOCK_STEPS = 16
#: Steps per epoch (BLOCK_STEPS blocks; the carry runs over the blocks of one epoch).
EPOCH_STEPS = BLOCK_STEPS * BLOCK_STEPS
_IDENTITY = (0.0, 0.0, 0.0, 1.0)

Quat = tuple[float, float, float, float]


def _product(a: Quat, b: Quat) -> Quat:
    """Hamilton product in plain floats: the expressions of :func:`.frames._hamilton_product`, same order."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz)


class AttitudeScan:
    """The attitude after each step, from the step rotations, with a call-independent association.

    Parameters
    ----------
    initial_xyzw : array_like
        (4,) attitude at step 0 (before the first rotation).
    """

    def __init__(self, initial_xyzw: ArrayLike) -> None:
        initial = np.asarray(initial_xyzw, dtype=np.float64)
        if initial.shape != (4,) or not np.all(np.isfinite(initial)):
            raise ValueError(f"initial_xyzw: expected 4 finite numbers, got {initial_xyzw!r}")
        self._epoch_start: Quat = tuple(float(v) for v in initial)  # E
        self._carry: Quat = _IDENTITY  # C_b of the open block
        self._inner: Quat | None = None  # I of the open block's last step (None: block empty)
        self._steps_in_epoch = 0
        self._left: Quat = _product(self._epoch_start, self._carry)  # E C_b of the open block
        self._attitude: Quat = self._epoch_start

    @property
    def attitude_xyzw(self) -> np.ndarray:
        """The attitude after the last step (the initial one before any), (4,)."""
        return np.array(self._attitude)

    def extend(self, rotations_xyzw: ArrayLike) -> np.ndarray:
        """Attitudes after each of the next n step rotations.

        Parameters
        ----------
        rotations_xyzw : array_like
            (n, 4) step rotations r_k (body frame, applied on the right).

        Returns
        -------
        numpy.ndarray
            (n, 4) attitudes q_{k+1}.
        """
        rotations = np.asarray(rotations_xyzw, dtype=np.float64)
        if rotations.ndim != 2 or rotations.shape[1] != 4:
            raise ValueError(f"rotations_xyzw: wrong shape {rotations.shape}, expected (n, 4)")
        count = rotations.shape[0]
        out = np.empty((count, 4))
        # to the next epoch boundary step by step; whole epochs and the rest vectorised
        head = min(count, (EPOCH_STEPS - self._steps_in_epoch) % EPOCH_STEPS)
        if count - head < EPOCH_STEPS:
            head = count  # a short call: plain floats are faster than numpy on a few steps
        rows_list = rotations[:head].tolist()
        for k in range(head):
            out[k] = self._step(tuple(rows_list[k]))
        if head < count:
            out[head:] = self._epochs(rotations[head:])
        return out

    def _step(self, rotation: Quat) -> Quat:
        inner = rotation if self._inner is None else _product(self._inner, rotation)
        attitude = _product(self._left, inner)
        self._steps_in_epoch += 1
        self._inner = inner
        if self._steps_in_epoch % BLOCK_STEPS == 0:  # block complete: its total joins the carry
            self._carry = inner if self._steps_in_epoch == BLOCK_STEPS else _product(self._carry, inner)
            self._inner = None
            if self._steps_in_epoch == EPOCH_STEPS:
                self._epoch_start, self._carry, self._steps_in_epoch = attitude, _IDENTITY, 0
            self._left = _product(self._epoch_start, self._carry)
        self._attitude = attitude
        return attitude

    def _epochs(self, rotations: np.ndarray) -> np.ndarray:
        """From an epoch boundary: whole epochs at once (the tail padded with identities)."""
        count = rotations.shape[0]
        epochs = -(-count // EPOCH_STEPS)
        blocks = epochs * BLOCK_STEPS
        padded = np.empty((blocks * BLOCK_STEPS, 4))
        padded[:count] = rotations
        padded[count:] = _IDENTITY
        # (4, position in block, block): component rows with the blocks side by side, one 2-D
        # transpose per component (long inner loops)
        rows = np.empty((4, BLOCK_STEPS, blocks))
        for axis in range(4):
            rows[axis] = padded[:, axis].reshape(blocks, BLOCK_STEPS).T
        scratch = np.empty(blocks)
        inner = np.empty_like(rows)
        inner[:, 0] = rows[:, 0]
        for position in range(1, BLOCK_STEPS):
            _hamilton_product(inner[:, position - 1], rows[:, position], inner[:, position], scratch)
        totals = inner[:, -1].reshape(4, epochs, BLOCK_STEPS)  # (4, epoch, block in epoch)
        carry = np.empty_like(totals)
        carry[:, :, 0] = np.array(_IDENTITY)[:, None]
        carry[:, :, 1] = totals[:, :, 0]
        for block in range(2, BLOCK_STEPS):
            _hamilton_product(carry[:, :, block - 1], totals[:, :, block - 1], carry[:, :, block], scratch[:epochs])
        starts = np.empty((4, epochs, 1))
        start = self._epoch_start
        last_carry, last_inner = carry[:, :, -1].T.tolist(), totals[:, :, -1].T.tolist()
        for epoch in range(epochs):  # E of each epoch: the last attitude of the one before
            starts[:, epoch, 0] = start
            start = _product(_product(start, tuple(last_carry[epoch])), tuple(last_inner[epoch]))
        left = np.empty_like(carry)  # E C_b
        _hamilton_product(starts, carry, left, np.empty(carry.shape[1:]))
        # the attitudes, into rows
        _hamilton_product(left.reshape(4, 1, blocks), inner, rows, np.empty(rows.shape[1:]))
        out = np.empty((blocks * BLOCK_STEPS, 4))
        by_block = out.reshape(blocks, BLOCK_STEPS, 4)
        for axis in range(4):
            by_block[:, :, axis] = rows[axis].T
        # the state after the last real step
        done = count - (epochs - 1) * EPOCH_STEPS  # steps of the last epoch, 1..EPOCH_STEPS
        if done == EPOCH_STEPS:
            self._epoch_start, self._carry, self._inner, self._steps_in_epoch = start, _IDENTITY, None, 0
        else:
            block, position = divmod(done, BLOCK_STEPS)
            self._epoch_start = tuple(starts[:, -1, 0].tolist())
            self._carry = tuple(carry[:, -1, block].tolist())
            self._inner = (None if position == 0
                           else tuple(inner[:, position - 1, (epochs - 1) * BLOCK_STEPS + block].tolist()))
            self._steps_in_epoch = done
        self._left = _product(self._epoch_start, self._carry)
        self._attitude = tuple(out[count - 1].tolist())
        return out[:count]
