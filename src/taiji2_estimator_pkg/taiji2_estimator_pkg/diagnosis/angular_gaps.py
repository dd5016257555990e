"""The angular acceleration that no GRS measured: what a bridged gap of both GRS leaves in the channels.

Where both GRS lost their samples, the bridge (:func:`.inputs._bridge_all`) takes the angular readout of
GRS1 from the command's step and its own neighbours, and GRS2 from that. The spacecraft's true angular
acceleration at those epochs (thruster torque noise over the inertia, plus the readout noise: the torque
channel's white noise, covariance ``C``) is then replaced by an interpolation, and every channel sees the
difference ``-delta_j`` as if it were a readout error common to both GRS (:mod:`.spectral`: the source
``nbar``). The star-tracker channel compares the attitude's second difference with ``B nbar``: its
nominal noise at low frequency is the star tracker's ``D2 eps``, which falls as f^2 (f^4 in PSD), while
a common readout error is flat. So the unmeasured angular acceleration, locally a few samples, is a
*rate* the channels lose for good: after whitening it is a random walk that dominates the star-tracker
channel below ~1 mHz (found on a 24-h ``deep_space`` recording, 2 % of each stream lost, most losses in
all streams at once: the star-tracker and ``lin_diff`` channels read 3 to 7 times their nominal power
at 0.1-1 mHz; the same losses cut from the batch simulation of the run read the same).

The bridged linear readouts follow the bridged angular ones (the map between the two GRS carries the
coupling ``m x (d_1 - d_2)``), so ``lin_diff`` does not see the error; the star-tracker and torque
channels do. A command change lost inside such a gap is worse: it is placed in the gap's middle
(:func:`.inputs._locate_lost_changes`), and m steps with it, so a placement off by e epochs leaves the
rate wrong by ``J^-1 step e dt``, for a maneuver step far more than the noise's. It took effect at any
of the gap's epochs that the GRS do not show, equally likely: the placement's mean square error e^2
over them (``(k^2 - 1) / 12`` for k contiguous epochs) is its variance (``DiagnosisInput.command_doubt``).

The diagnosis keeps the data and states the loss in its noise model instead: at low frequency the
defect of one bridged run of k epochs is its sum ``sum_j delta_j``. With the interpolation weights s_j
of GRS1's own gap (from the sample before, a, to the sample after, b), ``delta_j = x_j - (1 - s_j) x_a -
s_j x_b`` for white x of covariance C, so ``var(sum_j delta_j) = (k + (sum_j (1 - s_j))^2 + (sum_j
s_j)^2) C``: 1.5 C for one lost sample, 3.5 C per sample for five. :func:`angular_gap_weight` spreads
that factor over the run's epochs; its mean over the record is the variance, in units of C, of a white
error of m that :class:`.spectral.NoiseSpectrum` adds, with the misplaced changes' ``J^-1 step step^T
J^-T e^2`` averaged over the record (``DiagnosisInput.angular_loss``). A record without such
gaps adds nothing, and its spectra are unchanged to the bit.
"""

from __future__ import annotations

import numpy as np

__all__ = ["angular_gap_weight", "runs"]


def runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """[start, stop) of the runs of True in a (n,) bool array."""
    edges = np.flatnonzero(np.diff(np.concatenate(([0], mask.astype(np.int8), [0]))))
    return edges[0::2], edges[1::2]


def angular_gap_weight(grs1_received: np.ndarray, grs2_received: np.ndarray,
                       grs1_bridged: np.ndarray) -> np.ndarray:
    """(n,) per epoch: the angular acceleration lost there, in units of one epoch's white noise C.

    Parameters
    ----------
    grs1_received, grs2_received : numpy.ndarray
        (n,) bool: the epochs each GRS's own sample arrived on.
    grs1_bridged : numpy.ndarray
        (n,) bool: GRS1 present after its gaps were bridged from its own neighbours (received or
        interpolated); the interpolation that both GRS follow where neither was received.

    Returns
    -------
    numpy.ndarray
        (n,) float, 0 where some GRS measured the epoch or nothing was bridged; on each run of k epochs
        that neither GRS measured but the bridge filled, ``(k + (sum (1 - s))^2 + (sum s)^2) / k`` (module
        docstring), so that the run sums to the variance factor of its defect.
    """
    received1 = np.asarray(grs1_received, dtype=bool)
    unmeasured = ~received1 & ~np.asarray(grs2_received, dtype=bool) & np.asarray(grs1_bridged, dtype=bool)
    weight = np.zeros(received1.shape[0])
    if not np.any(unmeasured):
        return weight
    # the interpolation parameter s_j of each epoch inside GRS1's own bridged gap (a = start - 1, b = stop)
    s = np.zeros(received1.shape[0])
    for start, stop in zip(*runs(~received1 & np.asarray(grs1_bridged, dtype=bool)), strict=True):
        s[start:stop] = (np.arange(start, stop) - (start - 1)) / (stop - (start - 1))
    for start, stop in zip(*runs(unmeasured), strict=True):
        k = stop - start
        weight[start:stop] = (k + np.sum(1.0 - s[start:stop]) ** 2 + np.sum(s[start:stop]) ** 2) / k
    return weight
