"""The paper's c.m.-offset filter (``method: paper``), kept as written.

Per GRS a 3-state Kalman filter (Phi = I, Q = 0, Joseph update) on the TMRF linear acceleration
``a_out = G_lin (v1 + v2)``, ``H = C_i A~`` with A~ from the star tracker's smoothed rate and
acceleration, the same smoothing applied to a_out, and the paper's detrending (``Gamma t + Lambda``)
as extra diffuse states. Diagonal R. Its covariance is too small (reported, not fixed).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from taiji2_estimator_pkg.core.attitude import SmoothingDerivative
from taiji2_estimator_pkg.core.com_offset.estimate import ComOffsetEstimate
from taiji2_estimator_pkg.core.com_offset.model import cross_matrix
from taiji2_estimator_pkg.core.epoch_arrays import EpochArrays
from taiji2_estimator_pkg.core.instrument import InstrumentModel, linear_scale_factors
from taiji2_estimator_pkg.core.kalman import KalmanFilter
from taiji2_estimator_pkg.core.scale_factor.estimate import ScaleFactorEstimate
from taiji2_estimator_pkg.core.validation import InputValidator, ValidationOptions, validate_batch


@dataclass(frozen=True)
class PaperComOffsetOptions:
    """Options of the paper's c.m.-offset filter.

    Attributes
    ----------
    window : int
        Savitzky-Golay window of the star-tracker rate and acceleration [samples] (odd).
    polyorder : int
        Savitzky-Golay order.
    initial_sigma_m : float
        Initial 1-sigma of each d component (initial state: the nominal d) [m].
    detrend_sigma : float
        Initial 1-sigma of the detrending states, bias [m s^-2] (trend: this per 1000 s); large,
        i.e. effectively diffuse.
    gate_probability : float or None
        Chi-square gate (None: none, as in the paper).
    validation : ValidationOptions
        Input checks.
    """

    window: int = 2001
    polyorder: int = 2
    initial_sigma_m: float = 0.01
    detrend_sigma: float = 1e-6
    gate_probability: float | None = None
    validation: ValidationOptions = field(default_factory=ValidationOptions)


class PaperComOffsetFilter:
    """The paper's c.m.-offset filter, per GRS (Phi = I, Q = 0, Joseph update, diagonal R).

    State ``X = (d (3, CRF), Lambda (3, TMRF bias), Gamma (3, TMRF trend))``; measurement the
    TMRF linear acceleration smoothed like the regressor; ``H = [C_i A~, I, t I]`` with A~ from the
    star tracker's Savitzky-Golay rate and acceleration. The detrending states start diffuse
    (``detrend_sigma``), which equals detrending data and regressor together. Bulk only (the
    smoothing needs the record; per-sample nodes use :meth:`process_batch` on a buffer or the
    default method).

    Parameters
    ----------
    instrument : InstrumentModel
        Geometry, nominal d (initial state) and noise budget.
    grs_ids : sequence of int
        GRS to calibrate.
    options : PaperComOffsetOptions, optional
        Window, order, priors, gating.
    """

    method = "paper"

    def __init__(self, instrument: InstrumentModel, grs_ids: Sequence[int] = (1, 2),
                 options: PaperComOffsetOptions | None = None) -> None:
        self.instrument = instrument
        self.options = options or PaperComOffsetOptions()
        self.grs_ids = tuple(int(g) for g in grs_ids)
        self.smoother = SmoothingDerivative(self.options.window, self.options.polyorder, instrument.dt_s)
        noise = instrument.noise
        grs_gain = float(np.sum(self.smoother.grs_kernel() ** 2))
        thruster = noise.thruster_acceleration_variance()
        self.r = {}
        for g in self.grs_ids:
            c = instrument.c(g)
            tmrf = c @ np.diag(thruster) @ c.T
            self.r[g] = grs_gain * (np.diag(tmrf) + noise.linear_readout_variance())
        self.filters: dict[int, KalmanFilter] = {}
        self.validator = InputValidator(ValidationOptions(**{**self.options.validation.__dict__,
                                                             "grs_ids": self.grs_ids,
                                                             "sample_rate_hz": instrument.sample_rate_hz,
                                                             "star_tracker_sigma_rad": float(np.max(
                                                                 instrument.noise.star_tracker_sigma_rad))}))
        self.history: dict[Any, Any] = {}
        self.nis_mean = float("nan")

    def process_batch(self, t_s: ArrayLike, quat_xyzw: ArrayLike, voltages_v: ArrayLike,
                      scale_factors: ScaleFactorEstimate | Mapping[int, ArrayLike],
                      history_every: int = 0) -> ComOffsetEstimate:
        """Run the paper's filter over a record (closed form of the Phi = I, Q = 0 recursion).

        Parameters
        ----------
        t_s, quat_xyzw, voltages_v : array_like
            (n,), (n, 4), (n, n_grs, 6).
        scale_factors : ScaleFactorEstimate or mapping of int to array_like
            Angular G per GRS (the linear ones are ``r`` times them); the paper uses its own
            scale-factor result.
        history_every : int
            Keep the running estimate every that many updates in :attr:`history`.

        Returns
        -------
        ComOffsetEstimate
            With the filter's own (paper) covariance; no scale-factor propagation.
        """
        t = np.asarray(t_s, dtype=np.float64).reshape(-1)
        volts = np.asarray(voltages_v, dtype=np.float64).reshape(t.size, len(self.grs_ids), 6)
        checked = validate_batch(t, quat_xyzw, volts, self.validator.options, self.grs_ids)
        epochs = EpochArrays.build(checked, t, volts)
        w = self.options.window
        m = self.smoother.half
        count = epochs.count
        n_d = 3 * len(self.grs_ids)
        values = np.full(n_d, np.nan)
        cov = np.full((n_d, n_d), np.nan)
        if count < w + 1:
            return ComOffsetEstimate(self.grs_ids, values, cov, cov, np.zeros((n_d, n_d)), False, float("nan"),
                                     0, float("nan"))
        # windows usable: contiguous, star tracker and all GRS present
        good_st = epochs.st_ok
        good_grs = np.all(epochs.grs_ok, axis=1)
        pairs = np.diff(epochs.index) == 1
        starts = np.arange(count - w + 1)
        cum_st = np.concatenate(([0], np.cumsum(good_st)))
        cum_grs = np.concatenate(([0], np.cumsum(good_grs)))
        cum_pairs = np.concatenate(([0], np.cumsum(pairs)))
        usable = ((cum_st[starts + w] - cum_st[starts]) == w) & \
                 ((cum_grs[starts + w] - cum_grs[starts + 1]) == w - 1) & \
                 ((cum_pairs[starts + w - 1] - cum_pairs[starts]) == w - 1)
        rate_k, acc_k, grs_k = self.smoother.rate_kernel(), self.smoother.acceleration_kernel(), \
            self.smoother.grs_kernel()
        omega = np.stack([np.correlate(epochs.phi[:, a], rate_k, mode="valid") for a in range(3)], axis=1)
        omega_dot = np.stack([np.correlate(epochs.phi[:, a], acc_k, mode="valid") for a in range(3)], axis=1)
        omega, omega_dot = omega[usable], omega_dot[usable]
        centre = (starts + m)[usable]
        t_c = epochs.t[centre]
        tau = (t_c - t_c[0]) / 1000.0 if t_c.size else t_c
        a_tilde = cross_matrix(omega_dot) + cross_matrix(omega) @ cross_matrix(omega)
        g_values = self._angular(scale_factors)
        self.history = {"t_s": t_c}
        out_vals, out_cov = [], []
        nis_terms = []
        for i, g in enumerate(self.grs_ids):
            lin_sf = linear_scale_factors(g_values[g], self.instrument.linear_ratio_m)
            a_out = epochs.sums[:, i, :] * lin_sf[None, :]  # TMRF
            smoothed = np.stack([np.correlate(a_out[1:, a], grs_k, mode="valid") for a in range(3)], axis=1)[usable]
            c = self.instrument.c(g)
            h = np.zeros((centre.size, 3, 9))
            h[:, :, 0:3] = c[None] @ a_tilde
            h[:, :, 3:6] = np.eye(3)[None]
            h[:, :, 6:9] = np.eye(3)[None] * tau[:, None, None]
            x0 = np.concatenate((self.instrument.nominal_com_offsets[g], np.zeros(6)))
            s = self.options.detrend_sigma
            p0 = np.diag(np.concatenate((np.full(3, self.options.initial_sigma_m**2), np.full(6, s * s))))
            r_inv = 1.0 / self.r[g]
            info_terms = np.einsum("kji,j,kjl->kil", h, r_inv, h)
            vec_terms = np.einsum("kji,j,kj->ki", h, r_inv, smoothed)
            p0_inv = np.linalg.inv(p0)
            info = p0_inv + info_terms.sum(axis=0)
            vec = p0_inv @ x0 + vec_terms.sum(axis=0)
            p_n = np.linalg.inv(info)
            x_n = p_n @ vec
            kf = KalmanFilter(x_n, 0.5 * (p_n + p_n.T))
            kf.n_updates = centre.size
            self.filters[g] = kf
            resid = smoothed - np.einsum("kij,j->ki", h, x_n)
            nis_terms.append(np.mean(np.sum(resid * resid * r_inv, axis=1)) / 3.0)
            if history_every > 0:
                pick = np.arange(history_every - 1, centre.size, history_every)
                cum_info = p0_inv[None] + np.cumsum(info_terms, axis=0)[pick]
                cum_vec = (p0_inv @ x0)[None] + np.cumsum(vec_terms, axis=0)[pick]
                vals = np.linalg.solve(cum_info, cum_vec[..., None])[..., 0][:, :3]
                sig = np.sqrt(np.diagonal(np.linalg.inv(cum_info), axis1=1, axis2=2))[:, :3]
                self.history[g] = {"values": vals, "sigma": sig}
                self.history["t_s"] = t_c[pick]
            out_vals.append(x_n[:3])
            out_cov.append(p_n[:3, :3])
        values = np.concatenate(out_vals)
        cov = np.zeros((n_d, n_d))
        for i, block in enumerate(out_cov):
            cov[3 * i:3 * i + 3, 3 * i:3 * i + 3] = block
        self.nis_mean = float(np.mean(nis_terms))
        return ComOffsetEstimate(self.grs_ids, values, cov, cov.copy(), np.zeros((n_d, n_d)), True,
                                 float(epochs.t[-1]), int(centre.size), self.nis_mean,
                                 {k: dict(v) for k, v in checked.counts.items()}, self.method)

    def _angular(self, scale_factors: ScaleFactorEstimate | Mapping[int, ArrayLike]) -> dict[int, np.ndarray]:
        if isinstance(scale_factors, ScaleFactorEstimate):
            return {g: scale_factors.of(g)[0] for g in self.grs_ids}
        return {int(g): np.asarray(v, dtype=np.float64) for g, v in scale_factors.items()}


