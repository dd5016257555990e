"""Offline calibration of a whole record: scale factors, then c.m. offsets.

``calibrate(t, quats, voltages, instrument)`` runs the default method (or the paper's) in bulk on the
raw telemetry of one experiment (a bag read by an offline tool, or simulator output): star-tracker
quaternions (n, 4) and the GRS voltages (n, n_grs, 6) on a common stamp column.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from taiji2_estimator_pkg.core.com_offset.estimate import ComOffsetEstimate
from taiji2_estimator_pkg.core.com_offset.gls import ComOffsetEstimator
from taiji2_estimator_pkg.core.com_offset.model import ComOffsetOptions
from taiji2_estimator_pkg.core.com_offset.paper import PaperComOffsetFilter, PaperComOffsetOptions
from taiji2_estimator_pkg.core.instrument import InstrumentModel
from taiji2_estimator_pkg.core.parameters import NODE_DEFAULTS
from taiji2_estimator_pkg.core.scale_factor.estimate import ScaleFactorEstimate
from taiji2_estimator_pkg.core.scale_factor.gls import ScaleFactorEstimator
from taiji2_estimator_pkg.core.scale_factor.model import ScaleFactorOptions
from taiji2_estimator_pkg.core.scale_factor.paper import PaperScaleFactorFilter, PaperScaleFactorOptions

__all__ = ["CalibrationResult", "calibrate"]


@dataclass
class CalibrationResult:
    """Result of :func:`calibrate`.

    Attributes
    ----------
    method : str
        ``"gls"`` or ``"paper"``.
    scale_factors : ScaleFactorEstimate
        G of every GRS with the joint covariance.
    com_offsets : ComOffsetEstimate
        d of every GRS with the covariance (scale-factor uncertainty included for ``gls``).
    rates : numpy.ndarray or None
        (L, 3) filtered body rate at :attr:`rate_times` (``gls``), CRF [rad/s].
    rate_times : numpy.ndarray or None
        (L,) [s].
    """

    method: str
    scale_factors: ScaleFactorEstimate
    com_offsets: ComOffsetEstimate
    rates: np.ndarray | None = None
    rate_times: np.ndarray | None = None

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (JSON/YAML)."""
        return {"method": self.method, "scale_factors": self.scale_factors.to_dict(),
                "com_offsets": self.com_offsets.to_dict()}


def calibrate(t_s: ArrayLike, quat_xyzw: ArrayLike, voltages_v: ArrayLike, instrument: InstrumentModel,
              grs_ids: Sequence[int] = (1, 2), method: str = "gls",
              scale_factor_options: ScaleFactorOptions | PaperScaleFactorOptions | None = None,
              com_offset_options: ComOffsetOptions | PaperComOffsetOptions | None = None,
              use_rate_estimate: bool | None = None, star_tracker_offset_s: float = 0.0) -> CalibrationResult:
    """Calibrate G and d from one record in bulk.

    Parameters
    ----------
    t_s : array_like
        (n,) stamps [s] on the 1/fs grid (star tracker and GRS share them; NaN rows mark missing).
    quat_xyzw : array_like
        (n, 4) star-tracker attitude.
    voltages_v : array_like
        (n, n_grs, 6) voltages of ``grs_ids`` [V].
    instrument : InstrumentModel
        Geometry, nominal values, noise budget.
    grs_ids : sequence of int
        GRS in the columns of ``voltages_v``.
    method : str
        ``"gls"`` (default) or ``"paper"``.
    scale_factor_options, com_offset_options : optional
        Options of the two stages (of the chosen method).
    use_rate_estimate : bool, optional
        ``gls``: give the c.m.-offset stage the scale-factor stage's filtered body rate (its centripetal
        term). None: as the c.m.-offset node does by default (its parameter ``use_rate_estimate``, false),
        so that the offline estimate of a recording is the live node's computation on the same data (the
        24-h deep_space graph: 0.036 sigma of d apart with the rate, 1.2e-8 sigma without; docs/link.md).
    star_tracker_offset_s : float
        Time of every star-tracker readout after the stamp column's instant of its row [s] (the
        star tracker's constant offset, :mod:`taiji2_estimator_pkg.epochs`). ``gls``: the attitude is
        modelled at ``t + tau`` (:class:`~.scale_factor_model.ScaleFactorModel`); it overrides the
        value in ``scale_factor_options``. ``paper``: not modelled (its smoothing derivative takes the
        readouts at the rows' instants).

    Returns
    -------
    CalibrationResult
    """
    t = np.asarray(t_s, dtype=np.float64)
    if method == "gls":
        options = replace(scale_factor_options or ScaleFactorOptions(),  # type: ignore[type-var]
                          star_tracker_offset_s=float(star_tracker_offset_s))
        sf = ScaleFactorEstimator(instrument, grs_ids, options)
        g = sf.process_batch(t, quat_xyzw, voltages_v, want_rates=True)
        if use_rate_estimate is None:
            use_rate_estimate = bool(NODE_DEFAULTS["com_offset_estimator"]["use_rate_estimate"])
        rates = None
        if use_rate_estimate:  # the filtered body rate on the record's stamps (NaN where it has none)
            rates = np.full((t.size, 3), np.nan)
            if sf.rates is not None and sf.rate_times is not None:
                index = np.searchsorted(t, sf.rate_times)
                index = np.clip(index, 0, t.size - 1)
                exact = t[index] == sf.rate_times
                rates[index[exact]] = sf.rates[exact]
        co = ComOffsetEstimator(instrument, grs_ids, com_offset_options)  # type: ignore[arg-type]
        d = co.process_batch(t, voltages_v, rates, g)
        return CalibrationResult(method, g, d, sf.rates, sf.rate_times)
    if method == "paper":
        psf = PaperScaleFactorFilter(instrument, grs_ids, scale_factor_options)  # type: ignore[arg-type]
        g = psf.process_batch(t, quat_xyzw, voltages_v)
        pco = PaperComOffsetFilter(instrument, grs_ids, com_offset_options)  # type: ignore[arg-type]
        d = pco.process_batch(t, quat_xyzw, voltages_v, g)
        return CalibrationResult(method, g, d)
    raise ValueError(f"method: 'gls' or 'paper', got {method!r}")
