"""When the running estimates first meet each requirement, computed offline from a whole record.

The estimator cores run epoch by epoch over an aligned record (:func:`~taiji2_estimator_pkg.calibration.
align_streams`), as the nodes run them but without their lag: G is estimated at the first epoch of each
``estimate_period_s`` of data, and d right after it from the GRS data up to that epoch and that G. A
requirement is first met at the data time of the first such estimate whose 1-sigma meets it (G to 0.3 %,
d to 100 um, per GRS and axis: :data:`~taiji2_estimator_pkg.report.SCALE_FACTOR_REQUIREMENT_REL`,
:data:`~taiji2_estimator_pkg.report.COM_OFFSET_REQUIREMENT_M`). This is the reference the live ground's
requirement times (``taiji2 experiment --link``) are checked against: a live estimate that rests on data
up to time t cannot meet a requirement before the offline one does with all the data up to t.
"""

from __future__ import annotations

import math

import numpy as np

from taiji2_estimator_pkg.calibration import GRS_IDS, AlignedRecord
from taiji2_estimator_pkg.core.com_offset.gls import ComOffsetEstimator
from taiji2_estimator_pkg.core.instrument import InstrumentModel
from taiji2_estimator_pkg.core.parameters import DEFAULTS, com_offset_options, scale_factor_options
from taiji2_estimator_pkg.core.scale_factor.gls import ScaleFactorEstimator
from taiji2_estimator_pkg.report import COM_OFFSET_REQUIREMENT_M, SCALE_FACTOR_REQUIREMENT_REL

SCALE_FACTOR_NAMES = ("G_Pphi", "G_Ptheta", "G_Ppsi")
AXES = ("x", "y", "z")


def first_met_data_times(record: AlignedRecord, instrument: InstrumentModel, *, estimate_period_s: float = 1.0,
                         until_s: float = math.inf) -> list[dict]:
    """Data time [s] at which the offline running estimates first meet each requirement.

    Parameters
    ----------
    record : AlignedRecord
        The data on the 1/fs grid (NaN rows: missing).
    instrument : InstrumentModel
        Nominal model.
    estimate_period_s : float
        Data time between estimates [s] (the nodes' ``publish_period_s``, default 1.0).
    until_s : float
        Stop at this data time [s] (default: the whole record); the run stops earlier once every requirement
        is met.

    Returns
    -------
    list of dict
        Per GRS and parameter, in the order of the live report's requirements: ``grs``, ``parameter``
        (``G_Pphi`` ... ``d_z``), ``requirement`` and ``onboard_time_s`` (None: not met).
    """
    if not estimate_period_s > 0:
        raise ValueError(f"estimate_period_s: {estimate_period_s!r} is not a positive time")
    sf = ScaleFactorEstimator(instrument, GRS_IDS, scale_factor_options(dict(DEFAULTS["scale_factor_estimator"])))
    co = ComOffsetEstimator(instrument, GRS_IDS, com_offset_options(dict(DEFAULTS["com_offset_estimator"])))
    first: dict[tuple[int, str], float] = {}
    n_requirements = len(GRS_IDS) * (len(SCALE_FACTOR_NAMES) + len(AXES))
    period_ns = round(estimate_period_s * 1e9)
    last_period = None
    g = None
    for k in range(record.t_s.size):
        t = float(record.t_s[k])
        if t > until_s or len(first) == n_requirements:
            break
        q = record.quat_xyzw[k]
        voltages = {gid: record.voltages_v[k, gid - 1] for gid in GRS_IDS
                    if np.all(np.isfinite(record.voltages_v[k, gid - 1]))}
        sf.update(t, q if np.all(np.isfinite(q)) else None, voltages)
        period = round(t * 1e9) // period_ns
        due = period != last_period  # the first epoch of a new period, as the nodes publish
        last_period = period
        if due:
            estimate = sf.estimate()
            if estimate.determined:
                g = (estimate.values.copy(), estimate.covariance.copy())
                sigma = np.sqrt(np.diag(estimate.covariance))
                for i, (gid, name) in enumerate((gid, n) for gid in GRS_IDS for n in SCALE_FACTOR_NAMES):
                    if sigma[i] <= SCALE_FACTOR_REQUIREMENT_REL * abs(estimate.values[i]):
                        first.setdefault((gid, name), t)
        co.update(t, voltages, None, scale_factors=g)
        if due and g is not None:
            d = co.estimate(g)
            if d.determined:
                for gid in GRS_IDS:
                    sigma = np.sqrt(np.diag(d.of(gid)[1]))
                    for axis, s in zip(AXES, sigma, strict=True):
                        if s <= COM_OFFSET_REQUIREMENT_M:
                            first.setdefault((gid, f"d_{axis}"), t)
    out = []
    for gid in GRS_IDS:
        for name in (*SCALE_FACTOR_NAMES, *(f"d_{a}" for a in AXES)):
            out.append({"grs": gid, "parameter": name, "requirement": "100 um" if name.startswith("d_") else "0.3 %",
                        "onboard_time_s": first.get((gid, name))})
    return out
