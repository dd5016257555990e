"""The paper's scale-factor filter (``method: paper``), kept as written: Phi = I, Q = 0, Joseph update,
H = C^-1 U~, smoothed star-tracker acceleration."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from taiji2_estimator_pkg.core.attitude import AttitudeIntegrator, SmoothingDerivative
from taiji2_estimator_pkg.core.epoch_arrays import EpochArrays
from taiji2_estimator_pkg.core.instrument import InstrumentModel, angular_differences
from taiji2_estimator_pkg.core.kalman import KalmanFilter, chi2_gate
from taiji2_estimator_pkg.core.scale_factor.estimate import ScaleFactorEstimate, StepReport
from taiji2_estimator_pkg.core.validation import InputValidator, ValidationOptions, validate_batch


@dataclass(frozen=True)
class PaperScaleFactorOptions:
    """Options of the paper's scale-factor filter.

    Attributes
    ----------
    window : int
        Savitzky-Golay window [samples] (odd).
    polyorder : int
        Savitzky-Golay polynomial order.
    initial_sigma_fraction : float
        Initial 1-sigma of G as a fraction of the nominal value (P_0).
    gate_probability : float or None
        Chi-square gate (None: none, as in the paper).
    validation : ValidationOptions
        Input checks.
    """

    window: int = 2001
    polyorder: int = 2
    initial_sigma_fraction: float = 0.1
    gate_probability: float | None = None
    validation: ValidationOptions = field(default_factory=ValidationOptions)


class PaperScaleFactorFilter:
    """The paper's scale-factor filter, per GRS (3 states, Phi = I, Q = 0, Joseph update).

    Measurement ``Z_k = omega_dot_ST,k`` (CRF) from the Savitzky-Golay acceleration kernel on the
    small-angle attitude; ``H_k = C_i^-1 U~_k`` with U~ filtered by the equivalent GRS kernel;
    ``R = diag(sigma_ST^2 ||c||^2 + ||g||^2 diag(C_i^T Q_rot C_i))`` (per-sample variances, treated
    as white as in the paper). Outputs are delayed by ``window // 2`` samples (centred window).

    Parameters
    ----------
    instrument : InstrumentModel
        Geometry, nominal G (initial state) and noise budget.
    grs_ids : sequence of int
        GRS to calibrate (one independent filter each).
    options : PaperScaleFactorOptions, optional
        Window, polynomial order, initial uncertainty, gating.
    """

    method = "paper"

    def __init__(self, instrument: InstrumentModel, grs_ids: Sequence[int] = (1, 2),
                 options: PaperScaleFactorOptions | None = None) -> None:
        self.instrument = instrument
        self.options = options or PaperScaleFactorOptions()
        self.grs_ids = tuple(int(g) for g in grs_ids)
        self.smoother = SmoothingDerivative(self.options.window, self.options.polyorder, instrument.dt_s)
        self.kernel_st = self.smoother.acceleration_kernel()
        self.kernel_grs = self.smoother.grs_kernel()
        st_var = instrument.noise.star_tracker_variance() * float(np.sum(self.kernel_st**2))
        grs_gain = float(np.sum(self.kernel_grs**2))
        self.r = {g: st_var + grs_gain * np.diag(instrument.angular_noise_crf(g)) for g in self.grs_ids}
        gate = None if self.options.gate_probability is None else chi2_gate(3, self.options.gate_probability)
        self.filters = {}
        for g in self.grs_ids:
            g0 = instrument.nominal_scale_factors[g]
            self.filters[g] = KalmanFilter(g0, np.diag((self.options.initial_sigma_fraction * g0) ** 2), gate)
        self.validator = InputValidator(ValidationOptions(**{**self.options.validation.__dict__,
                                                             "grs_ids": self.grs_ids,
                                                             "sample_rate_hz": instrument.sample_rate_hz,
                                                             "star_tracker_sigma_rad": float(np.max(
                                                                 instrument.noise.star_tracker_sigma_rad))}))
        self.attitude = AttitudeIntegrator()
        w = self.options.window
        self._buffer_index: list[int] = []
        self._buffer_phi: list[np.ndarray | None] = []
        self._buffer_diff: list[dict[int, np.ndarray]] = []
        self._window = w
        self.t0_s: float | None = None
        self.t_last_s = float("nan")
        self.nis: dict[int, list[float]] = {g: [] for g in self.grs_ids}
        self._last_index: int | None = None

    def start_new_segment(self) -> None:
        """The next epoch starts a new segment: no smoothing window straddles the two (a restarted source)."""
        self._buffer_index.clear()
        self._buffer_phi.clear()
        self._buffer_diff.clear()

    def _measurements(self, phi_window: np.ndarray, diff_window: Mapping[int, np.ndarray]
                      ) -> tuple[np.ndarray, dict[int, np.ndarray]]:
        """Z (3,) and H per GRS from a complete window (phi: (2m+1, 3); U~: (2m, 3), epochs k-m+1..k+m)."""
        # Z_k = omega_dot_ST,k = sum_j c_j phi_{k+j}
        z = self.kernel_st @ phi_window
        h = {}
        for g in self.grs_ids:
            smoothed = self.kernel_grs @ diff_window[g]
            # H_k = C_i^-1 U~_k (smoothed U~, C_i^-1 = C_i^T)
            h[g] = self.instrument.c(g).T * smoothed[None, :]
        return z, h

    def update(self, t_s: float, quat_xyzw: ArrayLike | None = None,
               voltages: Mapping[int, ArrayLike] | None = None) -> StepReport:
        """Process one epoch; the filters update at the centre of the window (``window // 2`` epochs ago).

        Returns
        -------
        StepReport
            ``nis``: mean over the GRS filters of the NIS of the update made now (3 dof each; NaN if
            none); the per-GRS values are appended to :attr:`nis`.
        """
        rejections: list[tuple[str, str]] = []
        phi = None
        if quat_xyzw is not None:
            check = self.validator.check_star_tracker(t_s, quat_xyzw)
            if check.ok:
                phi = self.attitude.add(check.value)
            else:
                rejections.append(("star_tracker", str(check.reason)))
        diffs = {}
        for gid, v in (voltages or {}).items():
            check = self.validator.check_grs(t_s, int(gid), v)
            if check.ok:
                diffs[int(gid)] = angular_differences(check.value)
            else:
                rejections.append((f"grs{gid}", str(check.reason)))
        nothing = StepReport(float(t_s), float("nan"), float("nan"), False, tuple(rejections))
        if phi is None and not diffs:
            return nothing
        if self.t0_s is None:
            self.t0_s = float(t_s)
        index = round((float(t_s) - self.t0_s) * self.instrument.sample_rate_hz)
        if self._last_index is not None and index <= self._last_index:
            return StepReport(float(t_s), float("nan"), float("nan"), False,
                              (*rejections, ("epoch", "out_of_order_stamp")))
        self._last_index = index
        self.t_last_s = float(t_s)
        self._buffer_index.append(index)
        self._buffer_phi.append(phi)
        self._buffer_diff.append(diffs)
        if len(self._buffer_index) > self._window:
            del self._buffer_index[0], self._buffer_phi[0], self._buffer_diff[0]
        if len(self._buffer_index) < self._window:
            return nothing
        contiguous = self._buffer_index[-1] - self._buffer_index[0] == self._window - 1
        complete = all(p is not None for p in self._buffer_phi) and all(
            all(g in d for g in self.grs_ids) for d in self._buffer_diff[1:])
        if not (contiguous and complete):
            return nothing
        phi_window = np.stack(self._buffer_phi)  # type: ignore[arg-type]
        diff_window = {g: np.stack([d[g] for d in self._buffer_diff[1:]]) for g in self.grs_ids}
        z, h = self._measurements(phi_window, diff_window)
        values, accepted = [], True
        for g in self.grs_ids:
            kf = self.filters[g]
            kf.predict()  # Phi = I, Q = 0
            result = kf.update(z, h[g], self.r[g])
            self.nis[g].append(result.nis)
            values.append(result.nis)
            if not result.accepted:
                accepted = False
                rejections.append((f"grs{g}", "gated"))
        return StepReport(float(t_s), float(np.mean(values)), float("nan"), accepted, tuple(rejections))

    def process_batch(self, t_s: ArrayLike, quat_xyzw: ArrayLike, voltages_v: ArrayLike,
                      history_every: int = 0) -> ScaleFactorEstimate:
        """Bulk form: the same estimate as sample-by-sample :meth:`update` (closed-form sums).

        With Phi = I and Q = 0 the filter's result after N updates is
        ``P_N = (P_0^-1 + sum H^T R^-1 H)^-1``, ``X_N = P_N (P_0^-1 X_0 + sum H^T R^-1 Z)``.

        Parameters
        ----------
        t_s, quat_xyzw, voltages_v : array_like
            (n,), (n, 4), (n, n_grs, 6) as for :meth:`ScaleFactorEstimator.process_batch`.
        history_every : int
            If > 0, keep the running estimate and sigma every that many updates in
            :attr:`history` (dict: ``t_s``, per GRS ``values``/``sigma``).

        Returns
        -------
        ScaleFactorEstimate
        """
        t = np.asarray(t_s, dtype=np.float64).reshape(-1)
        volts = np.asarray(voltages_v, dtype=np.float64).reshape(t.size, len(self.grs_ids), 6)
        checked = validate_batch(t, quat_xyzw, volts, self.validator.options, self.grs_ids)
        epochs = EpochArrays.build(checked, t, volts)
        z, h_diag, t_mid = self._batch_measurements(epochs)
        self.history: dict[str, Any] = {"t_s": t_mid}
        for j, g in enumerate(self.grs_ids):
            kf = self.filters[g]
            c_t = self.instrument.c(g).T
            r_inv = 1.0 / self.r[g]
            h = c_t[None, :, :] * h_diag[:, j, None, :]  # (L, 3, 3)
            info_terms = np.einsum("kji,j,kjl->kil", h, r_inv, h)
            vec_terms = np.einsum("kji,j,kj->ki", h, r_inv, z)
            p0_inv = np.linalg.inv(kf.p)
            info = p0_inv + info_terms.sum(axis=0)
            vec = p0_inv @ kf.x + vec_terms.sum(axis=0)
            p_n = np.linalg.inv(info)
            if history_every > 0 and z.shape[0]:
                pick = np.arange(history_every - 1, z.shape[0], history_every)
                cum_info = p0_inv[None] + np.cumsum(info_terms, axis=0)[pick]
                cum_vec = (p0_inv @ kf.x)[None] + np.cumsum(vec_terms, axis=0)[pick]
                values = np.linalg.solve(cum_info, cum_vec[..., None])[..., 0]
                sigma = np.sqrt(np.diagonal(np.linalg.inv(cum_info), axis1=1, axis2=2))
                self.history[g] = {"values": values, "sigma": sigma}
                self.history["t_s"] = t_mid[pick]
            kf.x = p_n @ vec
            kf.p = 0.5 * (p_n + p_n.T)
            kf.n_updates += z.shape[0]
        self.t_last_s = float(epochs.t[-1]) if epochs.count else float("nan")
        return self.estimate()

    def _batch_measurements(self, epochs: EpochArrays) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Z (L, 3), smoothed U~ (L, n_grs, 3) and centre stamps (L,) of every complete window."""
        m = self.smoother.half
        count = epochs.count
        w = self._window
        if count < w:
            return np.zeros((0, 3)), np.zeros((0, len(self.grs_ids), 3)), np.zeros(0)
        # a window is usable if its epochs are contiguous and all inputs present
        good = epochs.st_ok.copy()
        good_grs = np.all(epochs.grs_ok, axis=1)
        contiguous_pairs = np.diff(epochs.index) == 1
        starts = np.arange(count - w + 1)
        cum_st = np.concatenate(([0], np.cumsum(good)))
        cum_grs = np.concatenate(([0], np.cumsum(good_grs)))
        cum_pairs = np.concatenate(([0], np.cumsum(contiguous_pairs)))
        usable = ((cum_st[starts + w] - cum_st[starts]) == w) & \
                 ((cum_grs[starts + w] - cum_grs[starts + 1]) == w - 1) & \
                 ((cum_pairs[starts + w - 1] - cum_pairs[starts]) == w - 1)
        z_all = np.stack([np.correlate(epochs.phi[:, a], self.kernel_st, mode="valid") for a in range(3)], axis=1)
        h_all = np.empty((starts.size, len(self.grs_ids), 3))
        for j in range(len(self.grs_ids)):
            for a in range(3):
                h_all[:, j, a] = np.correlate(epochs.diffs[1:, j, a], self.kernel_grs, mode="valid")
        centre = starts + m
        return z_all[usable], h_all[usable], epochs.t[centre[usable]]

    def estimate(self) -> ScaleFactorEstimate:
        """Estimate with the filter's own (paper) covariance, GRS stacked."""
        values = np.concatenate([self.filters[g].x for g in self.grs_ids])
        cov = np.zeros((3 * len(self.grs_ids),) * 2)
        for j, g in enumerate(self.grs_ids):
            cov[3 * j:3 * j + 3, 3 * j:3 * j + 3] = self.filters[g].p
        n = min(kf.n_updates for kf in self.filters.values())
        nis = [v for g in self.grs_ids for v in self.nis[g]]
        nis_mean = float(np.mean(nis) / 3.0) if nis else float("nan")
        return ScaleFactorEstimate(self.grs_ids, values, cov, n > 0, self.t_last_s, n, nis_mean,
                                   self.validator.count_summary(), self.method)

    def state_dict(self) -> dict[str, Any]:
        """Checkpoint (filters, buffers)."""
        return {
            "method": self.method, "grs_ids": list(self.grs_ids),
            "filters": {str(g): kf.state_dict() for g, kf in self.filters.items()},
            "validator": self.validator.state_dict(), "attitude": self.attitude.state_dict(),
            "buffer_index": list(self._buffer_index),
            "buffer_phi": [None if p is None else p.tolist() for p in self._buffer_phi],
            "buffer_diff": [{str(g): v.tolist() for g, v in d.items()} for d in self._buffer_diff],
            "t0_s": self.t0_s, "t_last_s": self.t_last_s, "last_index": self._last_index,
        }

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Resume from a :meth:`state_dict` checkpoint."""
        self.filters = {int(g): KalmanFilter.from_state_dict(s) for g, s in state["filters"].items()}
        self.validator.load_state_dict(state["validator"])
        self.attitude.load_state_dict(state["attitude"])
        self._buffer_index = list(state["buffer_index"])
        self._buffer_phi = [None if p is None else np.asarray(p) for p in state["buffer_phi"]]
        self._buffer_diff = [{int(g): np.asarray(v) for g, v in d.items()} for d in state["buffer_diff"]]
        self.t0_s = state["t0_s"]
        self.t_last_s = float(state["t_last_s"])
        self._last_index = state["last_index"]


