"""Exact noise spectra of the residual channels and the frequency-domain (Whittle) GLS.

Noise model
-----------
Every channel is a causal finite filter of independent white sources (the SRP acceleration, an
AR(1), is prewhitened in its channel), so with the DFT normalised as ``X_k = sum_j x_j
exp(-2 pi i j k / n) / sqrt(n)`` the channel vector at bin k has the covariance

    S_k = T(z_k) diag(v) T(z_k)^H,    z_k = exp(-2 pi i k / n),

exactly for the *circular* version of the channels; the data differ from it only in the leading
samples of the channels with memory, which the fit frees (impulse columns,
:func:`.channels.nuisance_columns`). Bins are then independent complex Gaussians: the Whittle
likelihood is exact, without taper or leakage. Sources (24, per-sample variance v):

star-tracker error (3), thruster torque (3), thruster force / M (3), SRP innovation (3),
angular readout noise of GRS1, GRS2 (3 + 3, TMRF), linear readout noise of GRS1, GRS2 (3 + 3).

Transfer T (P_i = C_i^T, nbar = (P_1 nR_1 + P_2 nR_2) / 2, D2 = (1 - z)^2 / dt^2, B = (1 + z)/2,
A = 1 - phi z):

- st = D2 eps - B nbar
- torque = J^-1 n_tau + nbar
- ang_diff = P_1 nR_1 - P_2 nR_2
- lin_common = A (F/M) + e_SRP + A [d_mean x] nbar + A (P_1 nL_1 + P_2 nL_2) / 2
- lin_diff = [(d_1 - d_2) x] nbar + P_1 nL_1 - P_2 nL_2

Where both GRS lost samples and the record bridged them, the angular acceleration there was not measured
(:mod:`.angular_gaps`): three more sources, a white error of the mean angular acceleration m with
covariance ``w C + J^-1 T J^-T`` (``angular_loss``: w the mean gap weight, C the torque channel's white
covariance, T the torque covariance of the command changes placed in doubt), in st (``- B``)
and torque (``+ 1``) only: the bridged linear readouts follow the bridged angular ones through the map
between the two GRS, so ``lin_diff`` and ``lin_common`` do not see it. u = 0 leaves the 24 sources and
the spectra unchanged.

Fit
---
The whitened residual ``w_k = L_k^-1 Y_k`` (``S_k = L_k L_k^H``) and whitened columns give, over
the bins 1..K (f <= f_max, DC dropped: a free offset per channel), the real least-squares problem
with rows ``sqrt(2) (Re, Im)``: unit variance per row, ``chi^2 = sum 2 |w|^2``, parameter
covariance ``(X^T X)^-1``.
"""

from __future__ import annotations

import functools
import hashlib
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.linalg import cho_factor, cho_solve

from taiji2_estimator_pkg.diagnosis.model import NominalModel

__all__ = ["ConditionedFit", "Design", "NoiseSpectrum", "Whitener", "dft", "skew"]

_CHUNK = 4096  # bins per block (memory only)


def skew(v: np.ndarray) -> np.ndarray:
    """(3, 3) matrix of ``v x``."""
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def dft(x: np.ndarray, k_max: int | None = None) -> np.ndarray:
    """``rfft(x, axis=0) / sqrt(n)``, bins 1..k_max (default: all below Nyquist).

    Parameters
    ----------
    x : numpy.ndarray
        (n, ...) real series.
    k_max : int, optional
        Last bin kept.

    Returns
    -------
    numpy.ndarray
        (K, ...) complex.
    """
    n = x.shape[0]
    top = (n - 1) // 2 if k_max is None else min(k_max, (n - 1) // 2)
    blocks = _pruning(n, top)
    if blocks is None:
        return np.fft.rfft(x, axis=0)[1:top + 1] / np.sqrt(n)
    length, count, twiddle = blocks
    # the low bins only (pruned): with t = m P + p, X_k = sum_p w^(pk) Y_p[k], Y_p the length-L DFT of the
    # p-th decimated series; L >= 2 top + 1 so that rfft gives Y_p[1..top] (P x fewer bins computed)
    rows = np.moveaxis(x.reshape(n, -1), 0, -1)  # (c, n): a view, contiguous for an (n, c) Fortran column
    y = np.fft.rfft(rows.reshape(rows.shape[0], length, count).transpose(0, 2, 1), axis=-1)[..., 1:top + 1]
    return np.einsum("cpk,kp->kc", y, twiddle).reshape((top, *x.shape[1:]))


@functools.lru_cache(maxsize=8)
def _pruning(n: int, top: int) -> tuple[int, int, np.ndarray] | None:
    """(L, P, twiddle (top, P) ``exp(-2 pi i k p / n) / sqrt(n)``) of the pruned DFT of :func:`dft`: L the
    least divisor of n with ``L >= 2 top + 1``; None where it saves little (L > n / 8)."""
    if top < 1:
        return None
    length = next(d for d in range(2 * top + 1, n + 1) if n % d == 0)
    if 8 * length > n:
        return None
    count = n // length
    k = np.arange(1, top + 1)
    return length, count, np.exp(-2j * np.pi * np.outer(k, np.arange(count)) / n) / np.sqrt(n)


class NoiseSpectrum:
    """Cross-spectral matrices of the 15 channels (exact for the circular channels).

    Parameters
    ----------
    model : NominalModel
        Noise budget, geometry, inertia.
    com_offset_m : numpy.ndarray
        (2, 3) d_i at the linearization point (the regressor noise ``n x d``) [m].
    n : int
        Record length (bins k correspond to f = k fs / n).
    angular_loss : tuple of (float, numpy.ndarray), optional
        The angular acceleration the record's bridged gaps did not measure
        (:attr:`.inputs.DiagnosisInput.angular_loss`): per epoch, a variance in units of the torque
        channel's white noise, and a (3, 3) torque covariance [N^2 m^2] of command changes placed in doubt.
    """

    def __init__(self, model: NominalModel, com_offset_m: np.ndarray, n: int,
                 angular_loss: tuple[float, np.ndarray] | None = None) -> None:
        self.model = model
        self.n = int(n)
        self._conditioned: tuple | None = None  # (key, arrays) of :meth:`_conditioning`
        self.variances = np.concatenate((model.var_st, model.var_torque, model.var_force_acc,
                                         model.var_srp_innovation, model.var_angular[0], model.var_angular[1],
                                         model.var_linear[0], model.var_linear[1]))
        d = np.asarray(com_offset_m, dtype=np.float64)
        half_p = 0.5 * model.p_crf
        self._half_p = half_p
        self._d_mean_x = skew(0.5 * (d[0] + d[1]))
        self._d_diff_x = skew(d[0] - d[1])
        # the error of m where no GRS measured it: m += F u (u white, unit), F F^T = w C + J^-1 T J^-T
        self._unmeasured_factor = None
        weight, torque_cov = angular_loss if angular_loss is not None else (0.0, np.zeros((3, 3)))
        if weight > 0.0 or np.any(torque_cov):
            white = model.inertia_inv @ np.diag(model.var_torque) @ model.inertia_inv.T + sum(
                p @ np.diag(v) @ p.T for p, v in zip(half_p, model.var_angular, strict=True))
            covariance = weight * white + model.inertia_inv @ np.asarray(torque_cov) @ model.inertia_inv.T
            eigenvalues, vectors = np.linalg.eigh(0.5 * (covariance + covariance.T))  # rank < 3 allowed
            self._unmeasured_factor = vectors * np.sqrt(np.maximum(eigenvalues, 0.0))[None, :]
            self.variances = np.concatenate((self.variances, np.ones(3)))

    def frequencies_hz(self, bins: np.ndarray) -> np.ndarray:
        """f_k = k fs / n [Hz]."""
        return np.asarray(bins, dtype=np.float64) * self.model.sample_rate_hz / self.n

    def transfer(self, bins: np.ndarray) -> np.ndarray:
        """(K, 15, 24) transfer T(z_k) from the sources to the channels."""
        model = self.model
        bins = np.asarray(bins)
        z = np.exp(-2j * np.pi * bins / self.n)
        count = z.shape[0]
        t = np.zeros((count, 15, self.variances.shape[0]), dtype=np.complex128)
        eye = np.eye(3)
        d2 = (1.0 - z) ** 2 / model.dt_s ** 2
        b = 0.5 * (1.0 + z)
        a = 1.0 - model.srp_decay * z
        hp1, hp2 = self._half_p
        # st
        t[:, 0:3, 0:3] = d2[:, None, None] * eye
        t[:, 0:3, 12:15] = -b[:, None, None] * hp1
        t[:, 0:3, 15:18] = -b[:, None, None] * hp2
        # torque
        t[:, 3:6, 3:6] = model.inertia_inv
        t[:, 3:6, 12:15] = hp1
        t[:, 3:6, 15:18] = hp2
        # ang_diff
        t[:, 6:9, 12:15] = 2.0 * hp1
        t[:, 6:9, 15:18] = -2.0 * hp2
        # lin_common
        t[:, 9:12, 6:9] = a[:, None, None] * eye
        t[:, 9:12, 9:12] = eye
        t[:, 9:12, 12:15] = a[:, None, None] * (self._d_mean_x @ hp1)
        t[:, 9:12, 15:18] = a[:, None, None] * (self._d_mean_x @ hp2)
        t[:, 9:12, 18:21] = a[:, None, None] * hp1
        t[:, 9:12, 21:24] = a[:, None, None] * hp2
        # lin_diff
        t[:, 12:15, 12:15] = self._d_diff_x @ hp1
        t[:, 12:15, 15:18] = self._d_diff_x @ hp2
        t[:, 12:15, 18:21] = 2.0 * hp1
        t[:, 12:15, 21:24] = -2.0 * hp2
        if self._unmeasured_factor is not None:  # a common error of m in st and torque (module docstring)
            f = self._unmeasured_factor
            t[:, 0:3, 24:27] = -b[:, None, None] * f
            t[:, 3:6, 24:27] = f
        return t

    def matrices(self, bins: np.ndarray) -> np.ndarray:
        """(K, 15, 15) S_k."""
        t = self.transfer(bins)
        return np.einsum("kcs,s,kds->kcd", t, self.variances, t.conj(), optimize=True)

    def marginal(self, bins: np.ndarray) -> np.ndarray:
        """(K, 15) diagonal of S_k (per-channel PSD in per-bin units)."""
        bins = np.asarray(bins)
        out = np.empty((bins.shape[0], 15))
        for start in range(0, bins.shape[0], _CHUNK):
            t = self.transfer(bins[start:start + _CHUNK])
            out[start:start + _CHUNK] = np.einsum("kcs,s->kc", (t * t.conj()).real, self.variances)
        return out

    def normalised(self, residual: np.ndarray, bins: np.ndarray, extra_st: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
        """Unit-variance views of a residual DFT, for the location scan.

        Parameters
        ----------
        residual : numpy.ndarray
            (K, 15) channel DFTs at ``bins``.
        bins : numpy.ndarray
            (K,) bins.
        extra_st : numpy.ndarray, optional
            (K, 3) extra star-tracker-channel spectrum.

        Returns
        -------
        marginal : numpy.ndarray
            (K, 15) ``Y_c / sqrt(S_cc)``: each channel against its own nominal spectrum.
        conditional : numpy.ndarray
            (K, 15) ``(S^-1 Y)_c / sqrt((S^-1)_cc)``: each channel's innovation given the 14 others
            (its part the others cannot predict); far more sensitive where a channel's noise is
            shared (e.g. the rotational noise times d in ``lin_diff``). Both are unit complex
            Gaussians per bin under the nominal model.
        """
        bins = np.asarray(bins)
        diag, scale, inverse, inverse_diag = self._conditioning(bins, extra_st)
        marginal = residual / np.sqrt(diag)
        conditional = np.empty_like(residual)
        for start in range(0, bins.shape[0], _CHUNK):
            part = slice(start, start + _CHUNK)
            y = residual[part] / scale[part]
            conditional[part] = np.einsum("kij,kj->ki", inverse[part], y) / np.sqrt(inverse_diag[part])
        return marginal, conditional

    def _conditioning(self, bins: np.ndarray, extra_st: np.ndarray | None
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Per bin: the channels' PSD, the per-block scale, the scaled inverse ``S^-1`` and its diagonal.

        Kept for the last (bins, extra) asked: the location scans and the "how far" rows view residuals
        against the same spectrum several times per diagnosis, and the inverses were most of their cost.
        """
        key = (bins.shape[0], int(bins[0]) if bins.size else 0, int(bins[-1]) if bins.size else 0,
               None if extra_st is None else hashlib.sha1(np.ascontiguousarray(extra_st).tobytes()).hexdigest())
        if self._conditioned is not None and self._conditioned[0] == key:
            return self._conditioned[1]
        count = bins.shape[0]
        diag = np.empty((count, 15))
        scale = np.empty((count, 15))
        inverse = np.empty((count, 15, 15), dtype=np.complex128)
        idx = np.arange(3)
        for start in range(0, count, _CHUNK):
            part = slice(start, start + _CHUNK)
            t = self.transfer(bins[part])
            s = np.einsum("kcs,s,kds->kcd", t, self.variances, t.conj(), optimize=True)
            if extra_st is not None:
                s[:, idx, idx] += extra_st[part]
            diag[part] = np.real(np.einsum("kcc->kc", s))
            block = np.sqrt(np.median(diag[part], axis=0))
            scale[part] = block[None, :]
            inverse[part] = np.linalg.inv(s / np.outer(block, block)[None])
        inverse_diag = np.real(np.einsum("kii->ki", inverse))
        self._conditioned = (key, (diag, scale, inverse, inverse_diag))
        return self._conditioned[1]

    def st_template(self, bins: np.ndarray, corner_hz: float) -> np.ndarray:
        """(K, 3) star-tracker-channel spectrum of an extra star-tracker error with knee f_knee = 1 Hz.

        The extra error is the AR(1) of :class:`taiji2_model.effect_catalog.StarTrackerLowFreqNoise`
        (PSD ``S_w f_knee^2 / (f^2 + f_c^2)``); it scales with f_knee^2, the fitted amplitude.
        """
        from taiji2_model.effect_catalog import StarTrackerLowFreqNoise

        model = self.model
        bins = np.asarray(bins)
        z = np.exp(-2j * np.pi * bins / self.n)
        sigma = np.sqrt(model.var_st)
        decay, innovation, _ = StarTrackerLowFreqNoise.ar1_parameters(sigma, 1.0, corner_hz, model.sample_rate_hz)
        d2 = np.abs((1.0 - z) ** 2 / model.dt_s ** 2) ** 2
        ar = 1.0 / np.abs(1.0 - decay * z) ** 2
        return (d2 * ar)[:, None] * innovation[None, :] ** 2


class Whitener:
    """Per-bin whitening ``L_k^-1`` of the channel vector (with a per-channel scale).

    Parameters
    ----------
    spectrum : NoiseSpectrum
        Channel spectra.
    bins : numpy.ndarray
        (K,) DFT bins used.
    extra_st : numpy.ndarray, optional
        (K, 3) additional star-tracker-channel PSD (per-bin units).
    """

    def __init__(self, spectrum: NoiseSpectrum, bins: np.ndarray, extra_st: np.ndarray | None = None) -> None:
        self.bins = np.asarray(bins)
        s = spectrum.matrices(self.bins)
        if extra_st is not None:
            idx = np.arange(3)
            s[:, idx, idx] += extra_st
        diag = np.real(np.einsum("kcc->kc", s))
        if np.any(diag <= 0.0):
            raise ValueError("nominal noise budget leaves a channel noise-free; the diagnosis needs every "
                             "noise source of its channels (enable them in the layout)")
        self.scale = np.sqrt(np.median(diag, axis=0))
        s = s / np.outer(self.scale, self.scale)[None]
        self.marginal = diag
        self.cholesky = np.linalg.cholesky(s)
        self.inverse = np.linalg.inv(self.cholesky)

    def apply(self, y: np.ndarray) -> np.ndarray:
        """Whiten (K, 15) or (K, 15, m) channel DFTs."""
        scaled = y / (self.scale[None, :, None] if y.ndim == 3 else self.scale[None, :])
        if y.ndim == 2:
            return np.einsum("kij,kj->ki", self.inverse, scaled)
        return np.matmul(self.inverse, scaled)

    def log_det(self) -> float:
        """sum_k log det S_k (with the scale)."""
        diag = np.real(np.einsum("kii->ki", self.cholesky))
        return float(2.0 * np.sum(np.log(diag)) + 2.0 * self.bins.shape[0] * np.sum(np.log(self.scale)))


def _real_rows(w: np.ndarray) -> np.ndarray:
    """(K, 15[, m]) complex -> (2 K 15[, m]) real rows sqrt(2) (Re, Im)."""
    flat = w.reshape(w.shape[0] * w.shape[1], *w.shape[2:])
    return np.sqrt(2.0) * np.concatenate((flat.real, flat.imag), axis=0)


@dataclass
class Design:
    """Normal equations of the whitened frequency-domain least squares over a set of columns.

    Attributes
    ----------
    names : list of str
        Column names.
    gram : numpy.ndarray
        (p, p) X^T X.
    xty : numpy.ndarray
        (p,) X^T y.
    yty : float
        y^T y (chi-square of the data alone).
    n_rows : int
        Real rows (2 K 15).
    x : numpy.ndarray or None
        (n_rows, p) whitened real rows of the columns (kept to replace a column cheaply).
    """

    names: list[str]
    gram: np.ndarray
    xty: np.ndarray
    yty: float
    n_rows: int
    x: np.ndarray | None = None
    yw: np.ndarray | None = None

    @classmethod
    def build(cls, whitener: Whitener, y_fft: np.ndarray, names: Sequence[str],
              column_ffts: Sequence[np.ndarray]) -> Design:
        """Whiten the data and the columns and form the normal equations.

        Parameters
        ----------
        whitener : Whitener
            Whitening at the bins of the DFTs.
        y_fft : numpy.ndarray
            (K, 15) residual channels.
        names : sequence of str
            Column names.
        column_ffts : sequence of numpy.ndarray
            (K, 15) each.
        """
        yw = _real_rows(whitener.apply(y_fft))
        p = len(column_ffts)
        gram = np.empty((p, p))
        xty = np.empty(p)
        blocks = []
        step = 24
        for start in range(0, p, step):
            stack = np.stack(column_ffts[start:start + step], axis=2)
            blocks.append(_real_rows(whitener.apply(stack)))
        x = np.concatenate(blocks, axis=1) if blocks else np.zeros((yw.shape[0], 0))
        gram[:] = x.T @ x
        xty[:] = x.T @ yw
        return cls(list(names), gram, xty, float(yw @ yw), int(yw.shape[0]), x, yw)

    def append(self, whitener: Whitener, names: Sequence[str], column_ffts: Sequence[np.ndarray]) -> None:
        """Add columns (e.g. the series of a polynomial signature)."""
        if self.x is None or self.yw is None:
            raise RuntimeError("design built without its rows")
        new = _real_rows(whitener.apply(np.stack(column_ffts, axis=2)))
        cross_term = self.x.T @ new
        p, q = self.gram.shape[0], new.shape[1]
        gram = np.empty((p + q, p + q))
        gram[:p, :p] = self.gram
        gram[:p, p:] = cross_term
        gram[p:, :p] = cross_term.T
        gram[p:, p:] = new.T @ new
        self.gram = gram
        self.xty = np.concatenate((self.xty, new.T @ self.yw))
        self.x = np.concatenate((self.x, new), axis=1)
        self.names = [*self.names, *names]

    def replace(self, whitener: Whitener, name: str, column_fft: np.ndarray) -> None:
        """Replace one column (e.g. a signature relinearised at its fitted magnitude)."""
        if self.x is None or self.yw is None:
            raise RuntimeError("design built without its rows")
        j = self.names.index(name)
        column = _real_rows(whitener.apply(column_fft[:, :, None]))[:, 0]
        self.x[:, j] = column
        row = self.x.T @ column
        self.gram[j, :] = row
        self.gram[:, j] = row
        self.xty[j] = float(column @ self.yw)

    def conditioned(self, indices: Sequence[int] | np.ndarray) -> ConditionedFit:
        """The fit of a fixed set of columns, factored once, to which columns that change are added
        (:class:`ConditionedFit`: a profile over a parameter that moves only the added columns)."""
        if self.x is None or self.yw is None:
            raise RuntimeError("design built without its rows")
        return ConditionedFit(self, np.asarray(indices, dtype=np.int64))

    def index(self, names: Sequence[str]) -> np.ndarray:
        """Column indices of ``names``."""
        lookup = {name: i for i, name in enumerate(self.names)}
        return np.array([lookup[name] for name in names], dtype=np.int64)

    def fit(self, indices: Sequence[int] | np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """Least squares on a subset of columns.

        Returns
        -------
        theta : numpy.ndarray
            (q,) estimates.
        cov : numpy.ndarray
            (q, q) covariance.
        chi2 : float
            Residual chi-square.
        """
        idx = np.asarray(indices, dtype=np.int64)
        if idx.size == 0:
            return np.zeros(0), np.zeros((0, 0)), self.yty
        gram = self.gram[np.ix_(idx, idx)]
        scale = np.sqrt(np.diag(gram))
        scale[scale == 0.0] = 1.0
        normalised = gram / np.outer(scale, scale)
        factor = cho_factor(normalised + 1e-13 * np.eye(idx.size))
        rhs = self.xty[idx] / scale
        theta = cho_solve(factor, rhs) / scale
        cov = cho_solve(factor, np.eye(idx.size)) / np.outer(scale, scale)
        chi2 = self.yty - float(self.xty[idx] @ theta)
        return theta, cov, chi2

    def chi2(self, indices: Sequence[int] | np.ndarray) -> float:
        """Residual chi-square of a subset of columns (without the covariance)."""
        idx = np.asarray(indices, dtype=np.int64)
        if idx.size == 0:
            return self.yty
        gram = self.gram[np.ix_(idx, idx)]
        scale = np.sqrt(np.diag(gram))
        scale[scale == 0.0] = 1.0
        factor = cho_factor(gram / np.outer(scale, scale) + 1e-13 * np.eye(idx.size))
        rhs = self.xty[idx] / scale
        return self.yty - float(rhs @ cho_solve(factor, rhs))

    def solve_with_offset(self, indices: Sequence[int] | np.ndarray, offset_indices: Sequence[int] | np.ndarray,
                          offset_theta: np.ndarray) -> np.ndarray:
        """Estimates of ``indices`` after subtracting fixed columns ``X_o theta_o``."""
        idx = np.asarray(indices, dtype=np.int64)
        o = np.asarray(offset_indices, dtype=np.int64)
        rhs = self.xty[idx] - self.gram[np.ix_(idx, o)] @ np.asarray(offset_theta, dtype=np.float64)
        gram = self.gram[np.ix_(idx, idx)]
        scale = np.sqrt(np.diag(gram))
        scale[scale == 0.0] = 1.0
        factor = cho_factor(gram / np.outer(scale, scale) + 1e-13 * np.eye(idx.size))
        return cho_solve(factor, rhs / scale) / scale

    def chi2_with_offset(self, indices: Sequence[int] | np.ndarray, offset_indices: Sequence[int] | np.ndarray,
                         offset_theta: np.ndarray) -> float:
        """Chi-square after subtracting fixed columns ``X_o theta_o`` and refitting ``indices``."""
        o = np.asarray(offset_indices, dtype=np.int64)
        theta_o = np.asarray(offset_theta, dtype=np.float64)
        yty = self.yty - 2.0 * float(self.xty[o] @ theta_o) + float(theta_o @ self.gram[np.ix_(o, o)] @ theta_o)
        idx = np.asarray(indices, dtype=np.int64)
        if idx.size == 0:
            return yty
        rhs = self.xty[idx] - self.gram[np.ix_(idx, o)] @ theta_o
        gram = self.gram[np.ix_(idx, idx)]
        scale = np.sqrt(np.diag(gram))
        scale[scale == 0.0] = 1.0
        factor = cho_factor(gram / np.outer(scale, scale) + 1e-13 * np.eye(idx.size))
        theta = cho_solve(factor, rhs / scale) / scale
        return yty - float(rhs @ theta)


class ConditionedFit:
    """Least squares of fixed columns ``X_o`` plus added columns ``W``, with ``X_o``'s part factored once.

    With ``G_oo = X_o^T X_o`` factored, the added columns enter through the Schur complement
    ``S = W^T W - C^T G_oo^-1 C`` (``C = X_o^T W``): their estimates ``S^-1 r`` with
    ``r = W^T y - C^T G_oo^-1 X_o^T y``, their covariance ``S^-1`` and the chi-square
    ``chi2_o - r^T S^-1 r``; the same as :meth:`Design.fit` of all the columns (to rounding), at the
    cost of the products with ``W`` only (the onset profile adds a candidate's columns at each trial
    onset to the same others).
    """

    def __init__(self, design: Design, indices: np.ndarray) -> None:
        self.yw = design.yw
        self.x_o = design.x[:, indices]
        gram = design.gram[np.ix_(indices, indices)]
        scale = np.sqrt(np.diag(gram)) if indices.size else np.ones(0)
        scale[scale == 0.0] = 1.0
        self.scale = scale
        self.factor = cho_factor(gram / np.outer(scale, scale) + 1e-13 * np.eye(indices.size)) if indices.size \
            else None
        self.b_o = design.xty[indices]
        self.a = self._solve(self.b_o[:, None])[:, 0]
        self.chi2_o = design.yty - float(self.b_o @ self.a)

    def _solve(self, rhs: np.ndarray) -> np.ndarray:
        if self.factor is None:
            return np.zeros_like(rhs)
        return cho_solve(self.factor, rhs / self.scale[:, None]) / self.scale[:, None]

    def projected_gram(self, whitener: Whitener, column_ffts: Sequence[np.ndarray]) -> np.ndarray:
        """``W^T W - C^T G_oo^-1 C``: the normal matrix of added columns with the fixed ones projected out
        (its normalised form is the correlation of their signatures beyond the fixed columns)."""
        w = _real_rows(whitener.apply(np.stack(column_ffts, axis=2)))
        c = self.x_o.T @ w
        return w.T @ w - c.T @ self._solve(c)

    def add(self, whitener: Whitener, column_ffts: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray, float]:
        """(estimates, covariance, chi2) of the added columns ((K, 15) DFTs each), the fixed ones refitted."""
        w = _real_rows(whitener.apply(np.stack(column_ffts, axis=2)))
        c = self.x_o.T @ w
        schur = w.T @ w - c.T @ self._solve(c)
        r = w.T @ self.yw - c.T @ self.a
        scale = np.sqrt(np.maximum(np.diag(schur), 0.0))
        scale[scale == 0.0] = 1.0
        cov = np.linalg.inv(schur / np.outer(scale, scale) + 1e-13 * np.eye(w.shape[1])) / np.outer(scale, scale)
        theta = cov @ r
        return theta, cov, self.chi2_o - float(r @ theta)
