"""Star-tracker epochs too long after the last GRS sample to be predicted.

The attitude filter is driven by the GRS angular acceleration; between GRS samples the last input is
held (``ScaleFactorEstimator._held_input``). Held for longer than ``max_bridged_gap_s`` it goes
stale across torque switches of the maneuver, the predicted attitude runs away from the star
tracker, and the chi-square gate then rejects the star tracker and, once the GRS return, the GRS
pairs as well (1,000 star-tracker and 625 GRS-pair rejections after a 100-s GRS dropout in a 300-s
Type-1 run). A star-tracker sample that far from any GRS input carries no information on G (the
input that would explain its motion is missing), so it is not used: counted as ``no_grs_input``,
and the data after the dropout start a new segment, as after a gap of every stream.
"""

from __future__ import annotations

import numpy as np

STALE_REASON = "no_grs_input"


def stale_star_tracker(t_s: np.ndarray, star_tracker_ok: np.ndarray, grs_present: np.ndarray,
                       max_gap_s: float) -> np.ndarray:
    """(n,) bool: accepted star-tracker rows without a GRS sample of their own whose last GRS sample
    (at any GRS) is more than ``max_gap_s`` [s] before them; rows before the first GRS sample are not
    stale (the filter starts with no input there).

    Parameters
    ----------
    t_s : numpy.ndarray
        (n,) stamps [s], non-decreasing over the rows considered.
    star_tracker_ok : numpy.ndarray
        (n,) accepted star-tracker rows.
    grs_present : numpy.ndarray
        (n, n_grs) accepted GRS rows.
    max_gap_s : float
        Longest time a GRS input is held [s].
    """
    n = star_tracker_ok.size
    if n == 0:
        return np.zeros(0, dtype=bool)
    any_grs = np.any(grs_present, axis=1)
    last = np.maximum.accumulate(np.where(any_grs, np.arange(n), -1))
    since = np.asarray(t_s, dtype=np.float64) - np.asarray(t_s, dtype=np.float64)[np.maximum(last, 0)]
    return star_tracker_ok & ~any_grs & (last >= 0) & (since > max_gap_s)
