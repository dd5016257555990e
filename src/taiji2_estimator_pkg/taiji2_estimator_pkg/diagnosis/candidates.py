"""Candidate model extensions: each catalog effect as a signature in the residual channels.

Length (over 600 lines): the one table of signatures below and the factory of each variant it lists, side by
side, so that a signature and its code are read and changed together.

Every catalog effect (:mod:`taiji2_model.effect_catalog`) is split into *variants*, one per GRS /
axis / readout it can act on, each with one parameter (the gravity gradient: the quadrature pair of
its 2n harmonic, and its mean, seen only where it starts mid-run), in the SI unit of the simulator's
parameter, so that a fitted magnitude can be compared with an injected one. A variant's columns are
the first-order change of the 15 channels per unit parameter, derived from the calibrated data at
the linearization point (:func:`.channels.perturbation_channels`). The star-tracker low-frequency
noise is a noise candidate: it changes the channel spectrum, not the residual
(:class:`NoiseCandidate`).

Signatures (data side, per unit magnitude; ``^pred`` = predicted from the commanded torque,
``^data`` = calibrated measurement; ``tc = t - t_mid``):

======================================  ==========================================================
scale_factor_drift[grs.pair]            angular and linear readout of the pair times ``-tc``
cross_coupling[grs.misalign_c]          ``-e_c x a`` on every angular and linear readout (TMRF)
cross_coupling[grs.imbalance_e]         angular ``+= l^data_e / r``, linear ``+= r alpha^pred_e``
time_offset                             star-tracker attitude ``-omega``
actuation_delay                         torque channel ``+ J^-1 (tau_act(D0 + tau) - tau_act(D0))``
thruster_response                       torque channel ``+ J^-1 (tau_act(T0 + T) - tau_act(T0))``
grs_time_offset                         actuation_delay(delta) + star-tracker attitude ``+omega delta``
thruster_torque_gain[k]                 torque channel ``+ J^-1 e_k tau_cmd,k``
com_drift[grs|both.c]                   linear ``+ tc (alpha^pred x e_c)`` of the GRS concerned
readout_nonlinearity[grs.readout]       readout ``+ k m^2 - 2 k^2 m^3 + 5 k^3 m^4 - ...`` (12 terms)
                                        (m the measured readout: the exact inverse of
                                        ``m = a + k a^2``; fitted by its series, see
                                        :meth:`.record.Record.series_fit`)
inertia_error[k] / [kl]                 torque channel ``- J^-1 dJ alpha^pred``
gravity_gradient[k]                     torque channel ``+ J^-1 e_k (cos 2nt, sin 2nt, 1)`` (the mean:
                                        only from an onset on; from the start it is the
                                        dropped DC bin)
tm_stiffness[grs.c]                     linear readout ``- H(s) l^data``
thruster_force_leakage[c.k]             spacecraft acceleration ``+ e_c tau_cmd,k / M``
star_tracker_lowfreq_noise              star-tracker channel PSD ``+ f_knee^2 x template``
======================================  ==========================================================

``tau_act`` is the exact mean thrust over each sample interval for a delay D and a lag T
(:func:`taiji2_model.timing.actuated_commands`); D0, T0 are the model's timing. A delay
moves the thrust of a zero-order-hold command between neighbouring samples: its signature is
exactly piecewise linear in the delay with kinks at whole samples, so the timing candidates are
fitted, like the nonlinearity, by an exact one-parameter scan: their series columns are the
signatures at knots (whole and half samples, and the model's own value), interpolated linearly.

Regressors are noise-free predictions wherever the measured quantity carries the noise of a
channel the column enters with the same sign structure (errors-in-variables bias, see
:class:`.channels.Linearization`); a cross product or a square of the measurement is unbiased.

Length (about 700 lines): the signature of every catalog variant, one small builder each, beside the shared
context they read; one table of candidates, kept in one place so that a new catalog effect is added here only.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy.signal import lfilter

from taiji2_estimator_pkg.diagnosis.channels import (
    TIMING_REACH_S,
    Linearization,
    Readouts,
    actuated_torque,
    perturbation_channels,
)
from taiji2_estimator_pkg.diagnosis.model import NominalModel
from taiji2_model.effect_catalog import (
    ANGULAR_READOUTS,
    ELECTRODE_PAIRS,
    LINEAR_READOUTS,
    GravityGradient,
    suspension_filter,
)
from taiji2_model.frames import cross

__all__ = ["FAMILIES", "ONSET_KINDS", "TIMING_FAMILIES", "Candidate", "CandidateContext", "NoiseCandidate",
           "candidate_catalog", "readout_change"]

FAMILIES = ("scale_factor_drift", "cross_coupling", "time_offset", "star_tracker_lowfreq_noise",
            "thruster_torque_gain", "com_drift", "readout_nonlinearity", "inertia_error", "gravity_gradient",
            "tm_stiffness", "thruster_force_leakage", "actuation_delay", "thruster_response", "grs_time_offset")
"""Effect families the diagnosis selects among (the catalog of the simulator, less ``impulse``: an impulse at an
unknown time is found by its own matched filter in the final residual, :mod:`.impulses`)."""

TIMING_FAMILIES = ("time_offset", "actuation_delay", "thruster_response", "grs_time_offset")
"""Families that are timing conventions (stamps, latency, thrust response), not physics."""

ONSET_KINDS = {family: "step" for family in (*FAMILIES, "impulse", "readout_step")}
ONSET_KINDS.update({"scale_factor_drift": "ramp", "com_drift": "ramp"})
"""How each family starts mid-run (docs/diagnosis.md): a drift starts drifting (``ramp``: its clock starts at
the onset), everything else switches on (``step``: the change is zero before the onset). Also the naming rule's
rival of a nonlinearity from an onset, a step of its readout (:mod:`.readout_step`; no catalog effect)."""

DELAY_RANGE_S = TIMING_REACH_S
"""Timing candidates are scanned over +-0.5 s around the model's delay (and 0 .. 1 s of lag)."""

_AXES = "xyz"

ACTUATED_KEPT = 48
"""(delay, lag) pairs whose thrust a context keeps (2.6 MB each for 3 h at 10 Hz; the knots are ~40)."""


@dataclass(frozen=True)
class CandidateContext:
    """What a signature needs: the linearization point, raw readouts, model and options.

    Attributes
    ----------
    lin : Linearization
    readouts : Readouts
    model : NominalModel
    orbit_period_s : float
        Orbit period of the gravity-gradient candidate [s].
    suspension_hz, damping : float
        Suspension of the tm_stiffness candidate.
    t_mid_s : float
        Reference time of the drifts [s] (middle of the full record).
    step_from_s, ramp_from_s : float or None
        Onset of the signature [s] (data clock): a step (every data-side change is zero before it) or
        a ramp (the drift clock ``max(t, onset) - t_mid``); None: present from the start.
    timing_base : dict
        Fitted timing the actuation signatures are conditioned on, beyond the model's:
        ``"delay_s"`` and ``"time_constant_s"`` (default 0). A delay's signature is then
        ``tau_act(D0 + d + tau, T0 + t) - tau_act(D0 + d, T0 + t)``, exact jointly with the lag ``t``
        fitted beside it (see ``diagnosis.joint_timing``).
    """

    lin: Linearization
    readouts: Readouts
    model: NominalModel
    orbit_period_s: float
    suspension_hz: float
    damping: float
    t_mid_s: float
    timing_base: dict[str, float] = field(default_factory=dict)
    step_from_s: float | None = None
    ramp_from_s: float | None = None
    actuated: dict[tuple[float, float], np.ndarray] = field(default_factory=dict, compare=False, repr=False)
    changes_log: list[dict[str, np.ndarray]] | None = field(default=None, compare=False, repr=False)
    """Where given, each signature's data-side changes before the step mask (:mod:`.step_onset`)."""

    def actuated_torque(self, delay_s: float, time_constant_s: float) -> np.ndarray:
        """Mean thrust torque (n, 3) [N m] of the raw commands under a delay and a lag
        (:func:`.channels.actuated_torque`), kept for the contexts derived from this one: the onset
        scans and the knot signatures ask for the same few (delay, lag) many times, and the thrust
        does not depend on the onset (the step is applied to the channel change)."""
        key = (float(delay_s), float(time_constant_s))
        moved = self.actuated.get(key)
        if moved is None:
            moved = actuated_torque(self.readouts.torque_raw_n_m, key[0], key[1], self.readouts.dt_s)
            if len(self.actuated) >= ACTUATED_KEPT:  # the joint timing fit visits continuous values
                self.actuated.pop(next(iter(self.actuated)))
            self.actuated[key] = moved
        return moved

    def at_onset(self, kind: str, onset_s: float | None) -> CandidateContext:
        """The context of a signature that starts at ``onset_s`` (None: from the start) as a ``"step"``
        (the data-side change is zero before it) or a ``"ramp"`` (a drift whose clock starts there)."""
        if onset_s is None:
            return replace(self, step_from_s=None, ramp_from_s=None)
        if kind == "ramp":
            return replace(self, step_from_s=None, ramp_from_s=float(onset_s))
        return replace(self, step_from_s=float(onset_s), ramp_from_s=None)


@dataclass(frozen=True)
class Candidate:
    """One variant of a catalog effect, linear in its parameters.

    Attributes
    ----------
    name : str
        Effect family (catalog name).
    variant : str
        Where it acts, e.g. ``"grs1.y"``.
    params : tuple of str
        Parameter names (one, or the quadrature pair of the gravity gradient and its mean).
    unit : str
        Unit of the magnitude.
    build : callable
        ``build(ctx) -> list of (n, 15) columns``.
    inject : callable
        ``inject(theta, model) -> dict``: the catalog effect (``{"name": ..., params}``) that
        produces this variant with these parameters (benchmarks, tests).
    series : callable or None
        ``series(ctx) -> columns c_1..c_m`` of a signature that is a polynomial in its (single)
        parameter: the channel change is ``sum_j coefficients(theta)_j c_j`` exactly to the order
        kept. Used when the second order matters (the readout nonlinearity: the square of the
        *measured* readout carries ``2 k a^3``, which for a readout that is a single square wave,
        whose square is nearly constant, can outweigh the first-order signature); None: linear.
    coefficients : callable or None
        ``coefficients(theta) -> (m,)`` weights of the series columns (``(G, m)`` for a (G,) array of
        magnitudes: the exact scan evaluates a grid at once).
    bound : callable or None
        ``bound(ctx) -> |theta| max`` where the series holds (for the nonlinearity: k a_max =
        :data:`NONLINEARITY_BOUND`).
    grid : numpy.ndarray or None
        Magnitudes the exact scan visits (timing candidates: their knot range); None: around the
        linear estimate.
    exact : callable or None
        ``exact(ctx, theta) -> (n, 15)``: the channel change at any magnitude, not interpolated
        (timing candidates; conditioned on ``ctx.timing_base``).
    series_term : callable or None
        ``series_term(ctx, j) -> c_j`` alone (knot signatures: a weighted sum of the series then builds
        only the knots of non-zero weight, two of them, instead of every knot; :meth:`series_sum`).
    leading : (int, callable) or None
        ``(m, leading_bound)``: the first m series terms alone hold while ``|theta| <= leading_bound(ctx)``
        (the exact scan first fits with them, and builds the others only beyond; needs ``series_term``).
    series_weighted : callable or None
        ``series_weighted(ctx, weights) -> sum_j weights_j c_j`` in one build, for a series whose terms are
        one linear map (:func:`.channels.perturbation_channels`) of data-side changes: the map applied once
        to the weighted sum of the changes (the nonlinearity: of the powers of the measured readout),
        instead of once per term (:meth:`series_sum`).
    """

    name: str
    variant: str
    params: tuple[str, ...]
    unit: str
    build: Callable[[CandidateContext], list[np.ndarray]]
    inject: Callable[[np.ndarray, NominalModel], dict[str, Any]]
    series: Callable[[CandidateContext], list[np.ndarray]] | None = None
    coefficients: Callable[[float], np.ndarray] | None = None
    bound: Callable[[CandidateContext], float] | None = None
    grid: np.ndarray | None = None
    exact: Callable[[CandidateContext, float], np.ndarray] | None = None
    series_term: Callable[[CandidateContext, int], np.ndarray] | None = None
    leading: tuple[int, Callable[[CandidateContext], float]] | None = None
    series_weighted: Callable[[CandidateContext, np.ndarray], np.ndarray] | None = None
    step_params: int = 0
    """The last ``step_params`` parameters act only from a step onset on: their columns are zero for an effect
    present from the start (a constant torque from the start is the dropped DC bin of its channel: the free
    offset absorbs it), so the effect has ``n_params`` parameters from the start and ``n_params_from_onset``
    from an onset."""

    def series_sum(self, ctx: CandidateContext, weights: np.ndarray) -> np.ndarray:
        """``sum_j weights_j c_j`` of the series columns; the terms of zero weight are not built when the
        candidate can build one term alone (the same sum: a zero term adds nothing), in one build where
        it can (:attr:`series_weighted`)."""
        if self.series_weighted is not None and np.any(weights):
            return self.series_weighted(ctx, np.asarray(weights, dtype=np.float64))
        if self.series_term is None or not np.any(weights):
            return sum(w * c for w, c in zip(weights, self.series(ctx), strict=True))
        return sum(w * self.series_term(ctx, j) for j, w in enumerate(weights) if w != 0.0)

    @property
    def is_timing(self) -> bool:
        """A timing convention rather than a physical effect."""
        return self.name in TIMING_FAMILIES

    @property
    def onset_kind(self) -> str:
        """``"step"`` or ``"ramp"`` (:data:`ONSET_KINDS`)."""
        return ONSET_KINDS[self.name]

    def series_names(self) -> list[str]:
        """Names of the series columns."""
        return [f"{self.key}:series{j}" for j in range(len(self.coefficients(1.0)))] if self.coefficients else []

    @property
    def key(self) -> str:
        """``name[variant]``."""
        return f"{self.name}[{self.variant}]" if self.variant else self.name

    @property
    def n_params(self) -> int:
        """Number of parameters of the effect present from the start (:attr:`step_params` excluded)."""
        return len(self.params) - self.step_params

    @property
    def n_params_from_onset(self) -> int:
        """Number of parameters of the effect from a step onset on."""
        return len(self.params)

    def n_params_at(self, onset_s: float | None) -> int:
        """Number of parameters of the effect from ``onset_s`` on (None: from the start)."""
        return self.n_params if onset_s is None else self.n_params_from_onset

    def magnitude(self, theta: np.ndarray, cov: np.ndarray) -> tuple[float, float]:
        """Magnitude and its 1-sigma: the parameter, or the amplitude of a quadrature pair (of the parameters
        present from the start; a step-only mean does not enter)."""
        q = self.n_params
        theta = np.asarray(theta, dtype=np.float64)[:q]
        cov = np.asarray(cov, dtype=np.float64)[:q, :q]
        if theta.size == 1:
            return float(theta[0]), float(math.sqrt(max(cov[0, 0], 0.0)))
        amplitude = float(np.hypot(*theta))
        if amplitude == 0.0:
            return 0.0, float(math.sqrt(max(np.trace(cov) / 2.0, 0.0)))
        gradient = theta / amplitude
        return amplitude, float(math.sqrt(max(gradient @ cov @ gradient, 0.0)))

    def column_names(self) -> list[str]:
        """Names of the design columns."""
        return [f"{self.key}:{p}" for p in self.params]


@dataclass(frozen=True)
class NoiseCandidate:
    """Star-tracker noise rising at low frequency (a spectral, not a residual, signature).

    The fitted amplitude is f_knee^2 [Hz^2] of :class:`~taiji2_model.effect_catalog.StarTrackerLowFreqNoise`
    (common to the three axes); the magnitude reported is f_knee [Hz].
    """

    name: str = "star_tracker_lowfreq_noise"
    variant: str = ""
    params: tuple[str, ...] = ("knee_hz_squared",)
    unit: str = "Hz"
    corner_hz: float = 1e-5

    @property
    def key(self) -> str:
        """The family name."""
        return self.name

    @property
    def n_params(self) -> int:
        """One amplitude."""
        return 1

    def inject(self, theta: np.ndarray, model: NominalModel) -> dict[str, Any]:
        """Catalog effect for a knee of ``sqrt(theta)``."""
        return {"name": self.name, "knee_hz": float(math.sqrt(max(float(np.ravel(theta)[0]), 0.0))),
                "corner_hz": self.corner_hz}

    @staticmethod
    def magnitude(kappa: float, sigma_kappa: float) -> tuple[float, float]:
        """(f_knee, sigma) from the fitted f_knee^2 and its sigma (delta method, sigma of sqrt)."""
        knee = math.sqrt(max(kappa, 0.0))
        if knee > 0.0:
            return knee, sigma_kappa / (2.0 * knee)
        return 0.0, math.sqrt(max(sigma_kappa, 0.0))


# ------------------------------------------------------------------------------------------------
# signature helpers
# ------------------------------------------------------------------------------------------------


def _tmrf_to_crf_column(ctx: CandidateContext, grs: int, axis: int, series: np.ndarray) -> np.ndarray:
    """(n, 2, 3) with GRS ``grs``'s CRF image of a series on TMRF axis ``axis``."""
    out = np.zeros((series.shape[0], 2, 3))
    out[:, grs] = np.outer(series, ctx.model.p_crf[grs][:, axis])
    return out


def _tmrf_vector_to_crf(ctx: CandidateContext, grs: int, vectors: np.ndarray) -> np.ndarray:
    out = np.zeros((vectors.shape[0], 2, 3))
    out[:, grs] = vectors @ ctx.model.p_crf[grs].T
    return out


def _centred_time(ctx: CandidateContext) -> np.ndarray:
    if ctx.ramp_from_s is not None:
        return np.maximum(ctx.readouts.t_s, ctx.ramp_from_s) - ctx.t_mid_s
    return ctx.readouts.t_s - ctx.t_mid_s


def _perturb(ctx: CandidateContext, **changes: np.ndarray) -> np.ndarray:
    """:func:`.channels.perturbation_channels` of data-side changes, zero before a step onset."""
    if ctx.changes_log is not None:
        ctx.changes_log.append({key: value for key, value in changes.items() if value is not None})
    if ctx.step_from_s is not None:
        on = (ctx.readouts.t_s >= ctx.step_from_s).astype(np.float64)
        changes = {key: value * on.reshape((-1,) + (1,) * (value.ndim - 1)) for key, value in changes.items()
                   if value is not None}
    return perturbation_channels(ctx.lin, ctx.model, **changes)


def _torque_column(ctx: CandidateContext, torque: np.ndarray) -> np.ndarray:
    """Channels of an unmodelled torque (n, 3) [N m] (or angular acceleration already)."""
    return _perturb(ctx, dtorque=torque @ ctx.model.inertia_inv.T)


def _unit(axis: int) -> np.ndarray:
    vector = np.zeros(3)
    vector[axis] = 1.0
    return vector


# ------------------------------------------------------------------------------------------------
# the catalog
# ------------------------------------------------------------------------------------------------


def _scale_factor_drift(grs: int, pair: str) -> Candidate:
    angular, linear = ELECTRODE_PAIRS[pair]

    def build(ctx: CandidateContext) -> list[np.ndarray]:
        tc = _centred_time(ctx)
        dg = _tmrf_to_crf_column(ctx, grs, angular, -tc * ctx.lin.ghat_pred[:, grs, angular])
        dl = _tmrf_to_crf_column(ctx, grs, linear, -tc * ctx.lin.lhat_pred[:, grs, linear])
        return [_perturb(ctx, dg=dg, dl=dl)]

    def inject(theta: np.ndarray, model: NominalModel) -> dict[str, Any]:
        return {"name": "scale_factor_drift", "rate_per_s": float(theta[0]), "grs": grs + 1, "axis": pair}

    return Candidate("scale_factor_drift", f"grs{grs + 1}.{pair}", ("rate_per_s",), "1/s", build, inject)


def _misalignment(grs: int, axis: int) -> Candidate:
    def build(ctx: CandidateContext) -> list[np.ndarray]:
        eps = _unit(axis)
        dg = _tmrf_vector_to_crf(ctx, grs, -cross(eps, ctx.lin.ghat[:, grs]))
        dl = _tmrf_vector_to_crf(ctx, grs, -cross(eps, ctx.lin.lhat[:, grs]))
        return [_perturb(ctx, dg=dg, dl=dl)]

    def inject(theta: np.ndarray, model: NominalModel) -> dict[str, Any]:
        return {"name": "cross_coupling", "grs": grs + 1, "misalignment_rad": (float(theta[0]) * _unit(axis)).tolist()}

    return Candidate("cross_coupling", f"grs{grs + 1}.misalign_{_AXES[axis]}", ("misalignment_rad",), "rad",
                     build, inject)


def _imbalance(grs: int, pair: str) -> Candidate:
    angular, linear = ELECTRODE_PAIRS[pair]
    pair_index = _AXES.index(pair)

    def build(ctx: CandidateContext) -> list[np.ndarray]:
        r = ctx.model.ratio_m
        dg = _tmrf_to_crf_column(ctx, grs, angular, ctx.lin.lhat[:, grs, linear] / r)
        dl = _tmrf_to_crf_column(ctx, grs, linear, r * ctx.lin.ghat_pred[:, grs, angular])
        return [_perturb(ctx, dg=dg, dl=dl)]

    def inject(theta: np.ndarray, model: NominalModel) -> dict[str, Any]:
        return {"name": "cross_coupling", "grs": grs + 1, "imbalance": (float(theta[0]) * _unit(pair_index)).tolist()}

    return Candidate("cross_coupling", f"grs{grs + 1}.imbalance_{pair}", ("imbalance",), "1", build, inject)


def _time_offset() -> Candidate:
    def build(ctx: CandidateContext) -> list[np.ndarray]:
        return [_perturb(ctx, datt=-ctx.lin.omega)]

    def inject(theta: np.ndarray, model: NominalModel) -> dict[str, Any]:
        return {"name": "time_offset", "offset_s": float(theta[0])}

    return Candidate("time_offset", "", ("offset_s",), "s", build, inject)


def _torque_gain(axis: int) -> Candidate:
    def build(ctx: CandidateContext) -> list[np.ndarray]:
        torque = np.zeros_like(ctx.readouts.torque_cmd_n_m)
        torque[:, axis] = ctx.readouts.torque_cmd_n_m[:, axis]
        return [_torque_column(ctx, torque)]

    def inject(theta: np.ndarray, model: NominalModel) -> dict[str, Any]:
        return {"name": "thruster_torque_gain", "gain": float(theta[0]), "axis": _AXES[axis]}

    return Candidate("thruster_torque_gain", _AXES[axis], ("gain",), "1", build, inject)


def _com_drift(which: int, axis: int) -> Candidate:
    grs_list = (0, 1) if which == 0 else (which - 1,)

    def build(ctx: CandidateContext) -> list[np.ndarray]:
        tc = _centred_time(ctx)
        motion = tc[:, None] * cross(ctx.lin.acc_pred, _unit(axis))
        dl = np.zeros((tc.shape[0], 2, 3))
        for g in grs_list:
            dl[:, g] = motion
        return [_perturb(ctx, dl=dl)]

    def inject(theta: np.ndarray, model: NominalModel) -> dict[str, Any]:
        return {"name": "com_drift", "rate_m_s": (float(theta[0]) * _unit(axis)).tolist(), "grs": which}

    label = "both" if which == 0 else f"grs{which}"
    return Candidate("com_drift", f"{label}.{_AXES[axis]}", ("rate_m_s",), "m/s", build, inject)


#: k a_max up to which the nonlinearity's series form is used (its radius of convergence is 1/4)
NONLINEARITY_BOUND = 0.2
#: terms of its inverse series: the first left out, C_13 (k a)^12, is 0.3 % of the effect k a^2 at the bound
#: (with the four terms kept before, 42 (k a)^4 = 7 %: a k of 3.5e7 on a Type-2 angular readout, at the bound,
#: was fitted 19 sigma off and its remainder selected as a cross-coupling and a torque gain, which moved the
#: corrected G 11 sigma from the truth)
NONLINEARITY_SERIES_TERMS = 12
#: the first terms alone, up to k a_max = NONLINEARITY_LEADING_BOUND (the first left out, 42 (k a)^4, is then
#: 0.03 % of the effect): the scan of every variant builds these; the others only for a k beyond (a 3-h
#: diagnosis took 46 s with all 12 built for all 24 variants, 29 s with 4)
NONLINEARITY_LEADING_TERMS = 4
NONLINEARITY_LEADING_BOUND = 0.05
_CATALAN = [math.comb(2 * n, n) // (n + 1) for n in range(NONLINEARITY_SERIES_TERMS + 2)]


def readout_change(ctx: CandidateContext, grs: int, readout: str, readout_series: np.ndarray) -> np.ndarray:
    """The (n, 15) channel change of ``readout_series`` added to GRS ``grs``'s (0 or 1) measured ``readout``
    (one of :data:`.channels.LINEAR_READOUTS` or :data:`.channels.ANGULAR_READOUTS`; SI units)."""
    if readout in ANGULAR_READOUTS:
        return _perturb(ctx, dg=_tmrf_to_crf_column(ctx, grs, ANGULAR_READOUTS.index(readout), readout_series))
    return _perturb(ctx, dl=_tmrf_to_crf_column(ctx, grs, LINEAR_READOUTS.index(readout), readout_series))


def _nonlinearity(grs: int, readout: str) -> Candidate:

    def measured(ctx: CandidateContext) -> np.ndarray:
        if readout in ANGULAR_READOUTS:
            return ctx.lin.ghat[:, grs, ANGULAR_READOUTS.index(readout)]
        return ctx.lin.lhat[:, grs, LINEAR_READOUTS.index(readout)]

    def powers(ctx: CandidateContext, exponents: Sequence[int]) -> list[np.ndarray]:
        m = measured(ctx)
        return [readout_change(ctx, grs, readout, m ** p) for p in exponents]

    def series_weighted(ctx: CandidateContext, weights: np.ndarray) -> np.ndarray:
        # sum_j w_j P(m^(j+2)) = P(m^2 sum_j w_j m^j): P is linear, one build instead of one per term
        m = measured(ctx)
        return readout_change(ctx, grs, readout, m ** 2 * np.polynomial.polynomial.polyval(m, weights))

    def build(ctx: CandidateContext) -> list[np.ndarray]:
        return powers(ctx, (2,))

    def series(ctx: CandidateContext) -> list[np.ndarray]:
        return powers(ctx, range(2, NONLINEARITY_SERIES_TERMS + 2))

    def series_term(ctx: CandidateContext, j: int) -> np.ndarray:
        return powers(ctx, (j + 2,))[0]

    def coefficients(theta: float | np.ndarray) -> np.ndarray:
        # a_meas = a + k a^2 inverted (m = a_meas): a = m sum_n C_n (-k m)^n (Catalan numbers C_n), so
        # k a^2 = m - a = sum_{j>=0} (-1)^j C_{j+1} k^(j+1) m^(j+2) = k m^2 - 2 k^2 m^3 + 5 k^3 m^4 - ...
        theta = np.asarray(theta, dtype=np.float64)
        return np.stack([(-1.0) ** j * _CATALAN[j + 1] * theta ** (j + 1)
                         for j in range(NONLINEARITY_SERIES_TERMS)], axis=-1)

    unit = "1/(rad s^-2)" if readout in ANGULAR_READOUTS else "1/(m s^-2)"

    def inject(theta: np.ndarray, model: NominalModel) -> dict[str, Any]:
        return {"name": "readout_nonlinearity", "k": float(theta[0]), "grs": grs + 1, "readout": readout}

    def a_max(ctx: CandidateContext) -> float:
        return max(float(np.max(np.abs(measured(ctx)))), 1e-300)

    def bound(ctx: CandidateContext) -> float:
        return NONLINEARITY_BOUND / a_max(ctx)

    def leading_bound(ctx: CandidateContext) -> float:
        return NONLINEARITY_LEADING_BOUND / a_max(ctx)

    return Candidate("readout_nonlinearity", f"grs{grs + 1}.{readout}", ("k",), unit, build, inject, series,
                     coefficients, bound, series_term=series_term,
                     leading=(NONLINEARITY_LEADING_TERMS, leading_bound), series_weighted=series_weighted)


def _inertia_diagonal(axis: int) -> Candidate:
    def build(ctx: CandidateContext) -> list[np.ndarray]:
        torque = np.zeros_like(ctx.lin.acc_pred)
        torque[:, axis] = -ctx.model.inertia_kg_m2[axis, axis] * ctx.lin.acc_pred[:, axis]
        return [_torque_column(ctx, torque)]

    def inject(theta: np.ndarray, model: NominalModel) -> dict[str, Any]:
        return {"name": "inertia_error", "relative": (float(theta[0]) * _unit(axis)).tolist()}

    return Candidate("inertia_error", _AXES[axis], ("relative",), "1", build, inject)


def _inertia_product(first: int, second: int) -> Candidate:
    index = {(0, 1): 0, (0, 2): 1, (1, 2): 2}[(first, second)]

    def build(ctx: CandidateContext) -> list[np.ndarray]:
        torque = np.zeros_like(ctx.lin.acc_pred)
        torque[:, first] = -ctx.lin.acc_pred[:, second]
        torque[:, second] = -ctx.lin.acc_pred[:, first]
        return [_torque_column(ctx, torque)]

    def inject(theta: np.ndarray, model: NominalModel) -> dict[str, Any]:
        products = np.zeros(3)
        products[index] = float(theta[0])
        return {"name": "inertia_error", "products_kg_m2": products.tolist()}

    return Candidate("inertia_error", f"{_AXES[first]}{_AXES[second]}", ("product_kg_m2",), "kg m^2", build, inject)


def _gravity_gradient(axis: int, orbit_period_s: float) -> Candidate:
    def build(ctx: CandidateContext) -> list[np.ndarray]:
        rate = 2.0 * math.pi / ctx.orbit_period_s
        start = ctx.readouts.t_s - ctx.readouts.dt_s  # torque held over the step from its start
        columns = []
        for wave in (np.cos, np.sin, np.ones_like):
            if wave is np.ones_like and ctx.step_from_s is None:  # the mean from the start: the dropped DC bin
                columns.append(np.zeros_like(columns[0]))  # (Candidate.step_params), not built
                continue
            torque = np.zeros((start.shape[0], 3))
            torque[:, axis] = wave(2.0 * rate * start)
            columns.append(_torque_column(ctx, torque))
        return columns

    def inject(theta: np.ndarray, model: NominalModel) -> dict[str, Any]:
        effect = GravityGradient(orbit_period_s=orbit_period_s)
        _, tau_c, tau_s = effect.harmonic_coefficients_n_m(model.inertia_kg_m2)
        unit_amplitude = float(np.hypot(tau_c[axis], tau_s[axis]))
        return {"name": "gravity_gradient", "orbit_period_s": orbit_period_s,
                "scale": float(np.hypot(theta[0], theta[1])) / unit_amplitude if unit_amplitude > 0 else 0.0}

    return Candidate("gravity_gradient", _AXES[axis], ("cos_n_m", "sin_n_m", "mean_n_m"), "N m", build, inject,
                     step_params=1)


def _tm_stiffness(grs: int, axis: int, suspension_hz: float, damping: float) -> Candidate:
    def build(ctx: CandidateContext) -> list[np.ndarray]:
        b, a = suspension_filter(ctx.suspension_hz, ctx.damping, ctx.model.sample_rate_hz)
        lag = lfilter(b, a, ctx.lin.lhat[:, grs, axis])
        dl = _tmrf_to_crf_column(ctx, grs, axis, -lag)
        return [_perturb(ctx, dl=dl)]

    def inject(theta: np.ndarray, model: NominalModel) -> dict[str, Any]:
        return {"name": "tm_stiffness", "stiffness_s2": float(theta[0]), "grs": grs + 1, "axis": _AXES[axis],
                "suspension_hz": suspension_hz, "damping": damping}

    return Candidate("tm_stiffness", f"grs{grs + 1}.{_AXES[axis]}", ("stiffness_s2",), "s^-2", build, inject)


def _force_leakage(force_axis: int, torque_axis: int) -> Candidate:
    def build(ctx: CandidateContext) -> list[np.ndarray]:
        acc = np.zeros_like(ctx.readouts.torque_cmd_n_m)
        acc[:, force_axis] = ctx.readouts.torque_cmd_n_m[:, torque_axis] / ctx.model.mass_kg
        return [_perturb(ctx, dacc=acc)]

    def inject(theta: np.ndarray, model: NominalModel) -> dict[str, Any]:
        matrix = np.zeros((3, 3))
        matrix[force_axis, torque_axis] = float(theta[0])
        return {"name": "thruster_force_leakage", "leakage_per_m": matrix.tolist()}

    return Candidate("thruster_force_leakage", f"F{_AXES[force_axis]}.T{_AXES[torque_axis]}", ("leakage_per_m",),
                     "1/m", build, inject)


def _actuation_change(ctx: CandidateContext, delay_s: float, time_constant_s: float) -> np.ndarray:
    """Torque-channel change (n, 15) when the thrust follows (D, T) instead of the model's timing."""
    model, raw = ctx.model, ctx.readouts.torque_raw_n_m
    if delay_s == model.delay_s and time_constant_s == model.time_constant_s:
        return np.zeros((raw.shape[0], 15))
    moved = ctx.actuated_torque(delay_s, time_constant_s)
    return _torque_column(ctx, moved - ctx.readouts.torque_cmd_n_m)


def _conditioned_change(ctx: CandidateContext, delay_s: float, time_constant_s: float) -> np.ndarray:
    """Torque-channel change (n, 15) of an extra delay and lag from the conditioned timing
    (the model's plus ``ctx.timing_base``): ``tau_act(D + delay, T + lag) - tau_act(D, T)``."""
    base_d = ctx.model.delay_s + ctx.timing_base.get("delay_s", 0.0)
    base_t = max(ctx.model.time_constant_s + ctx.timing_base.get("time_constant_s", 0.0), 0.0)
    moved = _actuation_change(ctx, base_d + delay_s, max(base_t + time_constant_s, 0.0))
    if base_d == ctx.model.delay_s and base_t == ctx.model.time_constant_s:
        return moved
    return moved - _actuation_change(ctx, base_d, base_t)


def _knot_candidate(name: str, param: str, knots: np.ndarray,
                    channels_at: Callable[[CandidateContext, float], np.ndarray],
                    inject: Callable[[np.ndarray, NominalModel], dict[str, Any]]) -> Candidate:
    """A one-parameter candidate whose signature is the linear interpolation of its knot signatures."""
    knots = np.unique(np.append(knots, 0.0))
    nonzero = knots[knots != 0.0]
    step = float(np.min(np.diff(knots)))

    def coefficients(theta: float | np.ndarray) -> np.ndarray:
        # hat functions: the weight of each non-zero knot at theta (the zero knot's column is zero)
        return np.stack([np.interp(theta, knots, (knots == knot).astype(float)) for knot in nonzero], axis=-1)

    def series(ctx: CandidateContext) -> list[np.ndarray]:
        return [channels_at(ctx, float(knot)) for knot in nonzero]

    def series_term(ctx: CandidateContext, j: int) -> np.ndarray:
        return channels_at(ctx, float(nonzero[j]))

    def build(ctx: CandidateContext) -> list[np.ndarray]:
        # the central secant over one knot step about 0 (exact where the signature is linear)
        half = 0.5 * step
        return [(channels_at(ctx, half) - channels_at(ctx, -half)) / step if knots[0] < 0.0
                else channels_at(ctx, step) / step]

    grid = np.unique(np.concatenate([np.linspace(knots[0], knots[-1], 2001), knots]))
    return Candidate(name, "", (param,), "s", build, inject, series, coefficients, None, grid, channels_at,
                     series_term)


def _actuation_delay(model_delay_s: float, dt_s: float) -> Candidate:
    absolute = np.arange(math.floor((model_delay_s - DELAY_RANGE_S) / (0.5 * dt_s)),
                         math.ceil((model_delay_s + DELAY_RANGE_S) / (0.5 * dt_s)) + 1) * 0.5 * dt_s

    def channels_at(ctx: CandidateContext, tau: float) -> np.ndarray:
        return _conditioned_change(ctx, tau, 0.0)

    def inject(theta: np.ndarray, model: NominalModel) -> dict[str, Any]:
        return {"name": "actuation_delay", "delay_s": float(theta[0])}

    return _knot_candidate("actuation_delay", "delay_s", absolute - model_delay_s, channels_at, inject)


def _grs_time_offset(model_delay_s: float, dt_s: float) -> Candidate:
    absolute = np.arange(math.floor((model_delay_s - DELAY_RANGE_S) / (0.5 * dt_s)),
                         math.ceil((model_delay_s + DELAY_RANGE_S) / (0.5 * dt_s)) + 1) * 0.5 * dt_s

    def channels_at(ctx: CandidateContext, delta: float) -> np.ndarray:
        # GRS stamped delta late = the physics delayed by delta, the star tracker read delta early
        torque = _conditioned_change(ctx, delta, 0.0)
        return torque + _perturb(ctx, datt=delta * ctx.lin.omega)

    def inject(theta: np.ndarray, model: NominalModel) -> dict[str, Any]:
        return {"name": "grs_time_offset", "offset_s": float(theta[0])}

    return _knot_candidate("grs_time_offset", "offset_s", absolute - model_delay_s, channels_at, inject)


def _thruster_response(model_time_constant_s: float) -> Candidate:
    absolute = np.array([0.0, 0.0125, 0.025, 0.0375, 0.05, 0.075, 0.1, 0.125, 0.15, 0.2, 0.25, 0.3, 0.4, 0.5,
                         0.7, 1.0])
    absolute = np.unique(np.append(absolute[absolute + 1e-12 >= 0.0], model_time_constant_s))

    def channels_at(ctx: CandidateContext, extra: float) -> np.ndarray:
        return _conditioned_change(ctx, 0.0, extra)

    def inject(theta: np.ndarray, model: NominalModel) -> dict[str, Any]:
        return {"name": "thruster_response", "time_constant_s": float(theta[0])}

    return _knot_candidate("thruster_response", "time_constant_s", absolute - model_time_constant_s, channels_at,
                           inject)


def candidate_catalog(families: Sequence[str] | None = None, orbit_period_s: float = 86164.1,
                      suspension_hz: float = 0.01, damping: float = 0.7, st_corner_hz: float = 1e-5,
                      model: NominalModel | None = None) -> tuple[list[Candidate], NoiseCandidate | None]:
    """All variants of the chosen effect families.

    Parameters
    ----------
    families : sequence of str, optional
        Names from :data:`FAMILIES` (default: all).
    orbit_period_s : float
        Orbit period of the gravity-gradient candidate [s].
    suspension_hz, damping : float
        Suspension of the tm_stiffness candidate.
    st_corner_hz : float
        Corner of the star-tracker low-frequency noise candidate [Hz].
    model : NominalModel, optional
        The nominal model, whose timing the timing candidates start from (default: the simulator's
        conventions at 10 Hz).

    Returns
    -------
    candidates : list of Candidate
        Deterministic variants.
    noise : NoiseCandidate or None
        The star-tracker noise candidate, if chosen.
    """
    chosen = list(FAMILIES) if families is None else list(families)
    unknown = [name for name in chosen if name not in FAMILIES]
    if unknown:
        raise ValueError(f"unknown candidate effect(s) {unknown}; known: {', '.join(FAMILIES)}")
    delay_s = model.delay_s if model is not None else 0.0
    time_constant_s = model.time_constant_s if model is not None else 0.0
    dt_s = model.dt_s if model is not None else 0.1
    out: list[Candidate] = []
    for family in chosen:
        if family == "scale_factor_drift":
            out += [_scale_factor_drift(g, p) for g in range(2) for p in "xyz"]
        elif family == "cross_coupling":
            out += [_misalignment(g, a) for g in range(2) for a in range(3)]
            out += [_imbalance(g, p) for g in range(2) for p in "xyz"]
        elif family == "time_offset":
            out.append(_time_offset())
        elif family == "thruster_torque_gain":
            out += [_torque_gain(a) for a in range(3)]
        elif family == "com_drift":
            out += [_com_drift(w, a) for w in (0, 1, 2) for a in range(3)]
        elif family == "readout_nonlinearity":
            out += [_nonlinearity(g, r) for g in range(2) for r in ANGULAR_READOUTS + LINEAR_READOUTS]
        elif family == "inertia_error":
            out += [_inertia_diagonal(a) for a in range(3)]
            out += [_inertia_product(a, b) for a, b in ((0, 1), (0, 2), (1, 2))]
        elif family == "gravity_gradient":
            out += [_gravity_gradient(a, orbit_period_s) for a in range(3)]
        elif family == "tm_stiffness":
            out += [_tm_stiffness(g, a, suspension_hz, damping) for g in range(2) for a in range(3)]
        elif family == "thruster_force_leakage":
            out += [_force_leakage(c, k) for c in range(3) for k in range(3)]
        elif family == "actuation_delay":
            out.append(_actuation_delay(delay_s, dt_s))
        elif family == "thruster_response":
            out.append(_thruster_response(time_constant_s))
        elif family == "grs_time_offset":
            out.append(_grs_time_offset(delay_s, dt_s))
    noise = NoiseCandidate(corner_hz=st_corner_hz) if "star_tracker_lowfreq_noise" in chosen else None
    return out, noise
