"""Impulsive events: a matched filter in the torque-response residual, each event fitted in six degrees of freedom.

A momentum kick far shorter than a sample (a micrometeoroid impact: LISA Pathfinder saw 54 in 4,348 h,
the smallest ~0.2 uN s) steps the spacecraft rate by ``J^-1 L`` and its velocity by ``p / M``. The
integrating GRS read the step as one sample of angular (and linear) acceleration ``J^-1 L / dt``
(``p / (M dt)``), passed through the readout chain's high-frequency response R(f) that the diagnosis
calibrates (:mod:`.dynamics`); the star tracker sees the same rate step, so the star-tracker channel,
which compares the two, does not.

Detection (:func:`detect_impulses`), on the torque channel ``m - J^-1 tau_cmd`` of the final model's
residual (every accepted effect and the chain's response removed), whose noise is white (thruster
torque noise and GRS angular readout noise, both white at 10 Hz) above the lowest bins:

- the residual's mean and slow part are taken out first: the local mean over :data:`BASELINE_HALF_WINDOW_S`
  either side of each sample (the template's own support left out of it, so an impulse does not lower its own
  amplitude). The fit drops the DC bin, so a mean torque the model does not hold (a gravity gradient's
  constant part) stays in the residual and makes the statistic below non-central: beside a gravity gradient
  whose x component was below the selection floor (a mean of -0.5 and 0.9 sigma on x and y), it exceeded its
  1e-3 and 1e-4 quantiles 5 and 7 times as often as chi-square says, and an "impulse" at SNR 6.0 was reported
  in 3 of 4 seeds; with the local mean removed the tail is chi-square's (102 and 9 exceedances where 108 and
  10.8 are expected);
- the template of axis a is the chain's impulse response h_a (the inverse DFT of the fitted R(f); one
  sample where R = 1); the matched filter ``c_a(k) = sum_j h_a(j) r_a(k + j)`` estimates the
  per-sample amplitude ``A_a(k) = c_a(k) / E_aa`` (``E_ab = sum_j h_a(j) h_b(j)``), whose 3x3
  covariance is taken from the amplitudes of the searched samples themselves, robustly (rows beyond
  5 sigma of any axis left out): for white noise it is ``C_ab E_ab / (E_aa E_bb)``, and where the
  readout chain colours the noise (an anti-alias filter correlates neighbouring samples) it stays right;
- the statistic ``T(k) = A(k)^T cov(A)^-1 A(k)`` is chi-square with 3 degrees of freedom without an
  impulse, ``SNR = sqrt(T)``; an impulse is reported where T exceeds the Bonferroni threshold
  ``chi2.isf(alpha / N, 3)`` over the N samples searched (alpha = :data:`FALSE_ALARM_PER_RECORD`:
  at most that probability of a reported impulse in a record of pure noise), strongest first, its
  neighbours (the template's support) then left out; more than :data:`MAX_IMPULSES` exceedances are not
  impulses but a residual the noise model does not describe (a timing convention left unfitted): none is
  reported, and the search says it stopped;
- within :data:`EDGE_GUARD_S` of a change of the commanded torque, a timing convention fitted slightly
  off leaves its residual; it is the same at every change of the same step, so the mean pattern of the
  other changes of that step is subtracted there (:mod:`.edge_pattern`) and those samples are searched
  too, except near a step seen fewer than 8 times; not searched: the record's ends that the torque
  channel leaves out, epochs the input estimated (bridged gaps).

Each event is then fitted in six degrees of freedom about its sample, at its time within the samples
(:func:`_sub_sample_fit`: a chain that smooths spreads a kick between two samples over both): the angular
momentum ``L = J A dt`` and, from the common linear channel (prewhitened by ``1 - phi z``: an impulse is the
doublet ``(1, -phi)`` there), the linear impulse (``p = M dt (l_k - phi l_{k+1}) / (1 + phi^2)`` for a kick
read as one sample), each with its covariance; its time is ``t_k - dt/2 + s dt`` for the fitted time ``s``
[samples] (1-sigma stated as ``dt / sqrt(12)``, the integrating readout's, where the time within a step is
unobservable). The fitted events become columns of the final model (:func:`impulse_candidate`),
so that the calibration and the residual scan are free of them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.stats import chi2

from taiji2_estimator_pkg.diagnosis.candidates import Candidate, CandidateContext, _perturb, _torque_column
from taiji2_estimator_pkg.diagnosis.channels import CHANNELS
from taiji2_estimator_pkg.diagnosis.dynamics import ResponseFit
from taiji2_estimator_pkg.diagnosis.edge_pattern import remove_edge_pattern
from taiji2_estimator_pkg.diagnosis.model import NominalModel

__all__ = ["BASELINE_HALF_WINDOW_S", "EDGE_GUARD_S", "FALSE_ALARM_PER_RECORD", "MAX_IMPULSES", "Impulse",
           "detect_impulses", "impulse_candidate", "local_baseline", "search_input", "shifted_template"]

FALSE_ALARM_PER_RECORD = 0.01
"""alpha: probability of one or more reported impulses in a record of pure noise (Bonferroni over samples)."""

EDGE_GUARD_S = 0.5
"""Samples this close to a change of the commanded torque [s] carry its timing residual: the change's pattern is
removed there (:mod:`.edge_pattern`), or, for a step seen too rarely, they are not searched."""

BASELINE_HALF_WINDOW_S = 10.0
"""Half-width [s] of the local mean subtracted from the torque residual before the matched filter: a mean or slow
residual is no impulse (the white-noise variance grows by dt / (2 x this), 0.5 % at 10 Hz)."""

MAX_IMPULSES = 50
"""More exceedances than this are not a few impulses but a residual the noise model does not describe:
the search stops, reports and fits none, and says so (``Impulses.abandoned``)."""

_TORQUE = slice(CHANNELS.index("torque_x"), CHANNELS.index("torque_x") + 3)
_LIN_COMMON = slice(CHANNELS.index("lin_common_x"), CHANNELS.index("lin_common_x") + 3)
_KERNEL_HALF = 4  # template taps either side of the impulse's sample
SUB_SAMPLE_SHIFTS = np.linspace(-1.0, 1.0, 41)
"""Times [samples, from the middle of the detected sample's step] tried for an impulse (:func:`_sub_sample_fit`)."""

SHIFT_GAIN_MIN = float(chi2.isf(0.01, 1))
"""A time off the detected sample's middle is taken only where it raises the statistic ``T`` by more than this
(6.6): an integrating readout leaves an impulse's time within its step unobservable, and noise alone then moves
the best time off the middle by this much in 1 % of impulses."""
_ROBUST_SIGMAS = 5.0


@dataclass(frozen=True)
class Impulse:
    """One detected impulsive event.

    Attributes
    ----------
    index : int
        Sample whose integration step holds the impulse.
    time_s, time_sigma_s : float
        Its time (the middle of that step) and 1-sigma [s].
    snr : float
        Matched-filter SNR in the torque-response residual, ``sqrt(T)``.
    angular_momentum_n_m_s, angular_momentum_cov : numpy.ndarray
        (3,) L, CRF [N m s], and its (3, 3) covariance.
    linear_impulse_n_s, linear_impulse_cov : numpy.ndarray
        (3,) p, CRF [N s], and its (3, 3) covariance.
    """

    index: int
    time_s: float
    time_sigma_s: float
    snr: float
    angular_momentum_n_m_s: np.ndarray
    angular_momentum_cov: np.ndarray
    linear_impulse_n_s: np.ndarray
    linear_impulse_cov: np.ndarray

    def to_dict(self) -> dict[str, Any]:
        """Report entry (SI units in the keys)."""
        return {"time_s": self.time_s, "time_sigma_s": self.time_sigma_s, "snr": self.snr,
                "angular_momentum_n_m_s": self.angular_momentum_n_m_s.tolist(),
                "angular_momentum_sigma_n_m_s": np.sqrt(np.diag(self.angular_momentum_cov)).tolist(),
                "linear_impulse_n_s": self.linear_impulse_n_s.tolist(),
                "linear_impulse_sigma_n_s": np.sqrt(np.diag(self.linear_impulse_cov)).tolist()}


@dataclass(frozen=True)
class Impulses:
    """The search's result: the events (strongest first), its threshold and what it searched."""

    events: list[Impulse]
    threshold_snr: float
    samples_searched: int
    abandoned: bool = False
    exceedances: int = 0

    def to_dict(self) -> dict[str, Any]:
        """Report entry."""
        return {"events": [event.to_dict() for event in self.events], "threshold_snr": self.threshold_snr,
                "samples_searched": self.samples_searched, "false_alarm_per_record": FALSE_ALARM_PER_RECORD,
                "abandoned": self.abandoned, "exceedances_when_abandoned": self.exceedances}


def chain_kernel(response: ResponseFit | None, dt_s: float) -> np.ndarray:
    """(3, 2 h + 1) impulse response of the readout chain per CRF axis, taps -h..h (h = 4), from the
    fitted R(f) (:meth:`.dynamics.ResponseFit.frequency_response_minus_one`)."""
    kernel = np.zeros((3, 2 * _KERNEL_HALF + 1))
    kernel[:, _KERNEL_HALF] = 1.0
    if response is None:
        return kernel
    size = 64
    frequencies = np.fft.fftfreq(size, dt_s)
    h = response.frequency_response_minus_one(frequencies)
    for axis in range(3):
        taps = np.real(np.fft.ifft(1.0 + h[axis]))
        kernel[axis] = np.roll(taps, _KERNEL_HALF)[:2 * _KERNEL_HALF + 1]
    return kernel


def _robust_cov(x: np.ndarray) -> np.ndarray:
    """3x3 covariance of the rows of ``x`` whose every component is within 5 robust sigmas (1.4826 MAD)."""
    centre = np.median(x, axis=0)
    sigma = 1.4826 * np.median(np.abs(x - centre), axis=0)
    inside = np.all(np.abs(x - centre) <= _ROBUST_SIGMAS * np.where(sigma > 0, sigma, np.inf), axis=1)
    core = x[inside]
    # a Gaussian cut at 5 sigma keeps all but 6e-7 of its variance: no correction needed
    return np.cov(core, rowvar=False)


def local_baseline(x: np.ndarray, weight: np.ndarray, half_window: int) -> np.ndarray:
    """(n, m) weighted mean of ``x`` (n, m) over ``half_window`` samples either side of each, the template's
    support (``+-_KERNEL_HALF`` samples) left out; ``weight`` (n,) 1 for the samples that may enter it."""
    ring = np.ones(2 * half_window + 1)
    ring[half_window - _KERNEL_HALF:half_window + _KERNEL_HALF + 1] = 0.0
    w = np.asarray(weight, dtype=np.float64)
    count = np.convolve(w, ring, mode="same")
    total = np.stack([np.convolve(x[:, a] * w, ring, mode="same") for a in range(x.shape[1])], axis=1)
    return total / np.maximum(count, 1.0)[:, None]


def search_input(residual: np.ndarray, torque_cmd_n_m: np.ndarray, torque_edges: tuple[int, int],
                 filled: np.ndarray | None, dt_s: float, t_s: np.ndarray | None = None,
                 model_steps_s: Sequence[float] = ()) -> tuple[np.ndarray, np.ndarray]:
    """The residual the search reads (the torque channel's patterns at the command changes removed,
    :mod:`.edge_pattern`) and the (n,) samples it may report: inside the torque channel's edges, measured (not
    bridged), not near a change whose step is too rare for its pattern, nor within :data:`EDGE_GUARD_S` of a
    modelled step (``model_steps_s`` [s], on the clock ``t_s``: the onsets of the named step effects). A modelled
    step is a change of the model's torque like a command change, seen once: its sharp column against the
    readout chain's smoothed step left a one-sample transient that read as an impulse at the onset (a gravity
    gradient from 1,800 s at 14 sigma of bias: an "impulse" at 1,800.05 s, SNR 8.8)."""
    n = residual.shape[0]
    cleaned, guarded = remove_edge_pattern(residual[:, _TORQUE], torque_cmd_n_m, math.ceil(EDGE_GUARD_S / dt_s))
    out = np.array(residual, copy=True)
    out[:, _TORQUE] = cleaned
    keep = np.zeros(n, dtype=bool)
    head, tail = torque_edges
    keep[head + _KERNEL_HALF:n - tail - _KERNEL_HALF - 1] = True
    keep &= ~guarded
    if filled is not None:
        bridged = np.convolve(np.asarray(filled, dtype=float), np.ones(2 * _KERNEL_HALF + 1), mode="same") > 0
        keep &= ~bridged
    if t_s is not None:
        for onset in model_steps_s:
            keep &= np.abs(np.asarray(t_s) - onset) > EDGE_GUARD_S + _KERNEL_HALF * dt_s
    return out, keep


def detect_impulses(residual: np.ndarray, response: ResponseFit | None, model: NominalModel, t_s: np.ndarray,
                    keep: np.ndarray) -> Impulses:
    """Impulsive events in the residual channels (see the module doc).

    Parameters
    ----------
    residual : numpy.ndarray
        (n, 15) residual channels of the final model (:meth:`.record.Record.residual_time`).
    response : ResponseFit or None
        The chain's fitted high-frequency response (None: an ideal integrating readout).
    model : NominalModel
        Inertia, mass, dt and the SRP prewhitening coefficient.
    t_s : numpy.ndarray
        (n,) sample stamps [s] (the end of each sample's integration step).
    keep : numpy.ndarray
        (n,) samples the search may report (:func:`search_input`, which also gives the residual).

    Returns
    -------
    Impulses
    """
    dt = model.dt_s
    torque = residual[:, _TORQUE]
    torque = torque - local_baseline(torque, keep, round(BASELINE_HALF_WINDOW_S / dt))
    kernel = chain_kernel(response, dt)
    energy = kernel @ kernel.T  # E_ab
    c = np.stack([np.correlate(torque[:, a], kernel[a], mode="same") for a in range(3)], axis=1)
    amplitude = c / np.diag(energy)
    # the amplitudes' covariance from the amplitudes themselves (robustly): exact for white noise, where it is
    # C_ab E_ab / (E_aa E_bb), and still right where the chain colours the noise (an anti-alias filter
    # correlates neighbouring samples, which the white formula would take for signal)
    cov_a = _robust_cov(amplitude[keep])
    info = np.linalg.inv(cov_a)
    statistic = np.einsum("ka,ab,kb->k", amplitude, info, amplitude)
    searched = int(np.count_nonzero(keep))
    threshold = float(chi2.isf(FALSE_ALARM_PER_RECORD / max(searched, 1), 3))
    open_ = keep.copy()
    linear = residual[:, _LIN_COMMON]
    cov_l = _robust_cov(linear[keep])
    phi = model.srp_decay
    events: list[Impulse] = []
    while True:
        scores = np.where(open_, statistic, -np.inf)
        k = int(np.argmax(scores))
        if not scores[k] > threshold:
            break
        if len(events) == MAX_IMPULSES:  # not a few impulses: none of them is reported or fitted
            return Impulses([], math.sqrt(threshold), searched, abandoned=True, exceedances=len(events) + 1)
        open_[max(0, k - 2 * _KERNEL_HALF):k + 2 * _KERNEL_HALF + 1] = False
        fit = _sub_sample_fit(torque, k, kernel, cov_a)
        # the linear impulse: the same template (the axes' mean) through the common channel's prewhitening 1 - phi z
        shape = np.mean(fit.template, axis=0)
        doublet = np.append(shape, 0.0) - phi * np.append(0.0, shape)
        rows = np.arange(k - _KERNEL_HALF - 1, k + _KERNEL_HALF + 3)
        inside = (rows >= 0) & (rows < linear.shape[0])
        weight = float(doublet @ doublet)
        dv = dt * (doublet[inside] @ linear[rows[inside]]) / weight
        events.append(Impulse(
            index=k + math.floor(fit.shift + 0.5), time_s=float(t_s[k] - 0.5 * dt + fit.shift * dt),
            time_sigma_s=dt / math.sqrt(12.0), snr=float(math.sqrt(statistic[k])),
            angular_momentum_n_m_s=model.inertia_kg_m2 @ fit.amplitude * dt,
            angular_momentum_cov=model.inertia_kg_m2 @ fit.cov @ model.inertia_kg_m2.T * dt * dt,
            linear_impulse_n_s=model.mass_kg * dv,
            linear_impulse_cov=cov_l * (model.mass_kg * dt) ** 2 / weight))
    return Impulses(events, math.sqrt(threshold), searched)


@dataclass(frozen=True)
class _SubSampleFit:
    shift: float
    template: np.ndarray
    amplitude: np.ndarray
    cov: np.ndarray


def shifted_template(kernel: np.ndarray, shift: float) -> np.ndarray:
    """(3, 2 h + 3) template, taps -h-1..h+1, of an impulse ``shift`` samples (|shift| <= 1) from the middle of its
    sample's step: the chain's kernel there and at the neighbouring sample, in the proportions ``1 - |shift|`` and
    ``|shift|`` (each sample's step holds the part of a chain's smooth response nearest it)."""
    template = np.zeros((kernel.shape[0], kernel.shape[1] + 2))
    template[:, 1:-1] = (1.0 - abs(shift)) * kernel
    if shift > 0.0:
        template[:, 2:] += shift * kernel
    elif shift < 0.0:
        template[:, :-2] += -shift * kernel
    return template


def _sub_sample_fit(torque: np.ndarray, k: int, kernel: np.ndarray, cov_a: np.ndarray) -> _SubSampleFit:
    """The impulse about sample ``k``: the time (among :data:`SUB_SAMPLE_SHIFTS`) whose template
    (:func:`shifted_template`) gives the largest statistic ``T = A^T cov^-1 A``, its amplitudes A (3,) and their
    covariance (``cov_a`` of the sample's own template, scaled per axis by the templates' energies: white noise).

    An integrating readout reads an impulse anywhere in a sample's step as that one sample; a chain that smooths
    (an anti-alias filter before decimation) spreads it over the two samples about it in the proportions of its
    time between them, and the one-sample template read a kick between two samples at 0.66-0.88 of its size
    (blind seed 17, set 76, reference fidelity: -8.2 and -13.6 of a -25.6 kick on two samples). The sample's own
    template (shift 0) is kept unless another time beats it by :data:`SHIFT_GAIN_MIN`."""
    n, span = torque.shape[0], _KERNEL_HALF + 1
    first, last = max(0, k - span), min(n, k + span + 1)
    taps = slice(first - (k - span), last - (k - span))
    energy_own = np.sum(kernel ** 2, axis=1)

    def fit(shift: float) -> tuple[float, _SubSampleFit]:
        template = shifted_template(kernel, shift)
        energy = np.sum(template ** 2, axis=1)
        amplitude = np.einsum("aj,ja->a", template[:, taps], torque[first:last]) / energy
        scale = np.sqrt(energy_own / energy)
        cov = cov_a * np.outer(scale, scale)
        return float(amplitude @ np.linalg.solve(cov, amplitude)), _SubSampleFit(shift, template, amplitude, cov)

    own_statistic, best = fit(0.0)
    threshold = own_statistic + SHIFT_GAIN_MIN
    for shift in SUB_SAMPLE_SHIFTS:
        value, candidate = fit(float(shift))
        if value > threshold:
            threshold, best = value, candidate
    return best


def impulse_candidate(event: Impulse, model: NominalModel) -> Candidate:
    """The event as six linear columns of the fit (L [N m s], p [N s] at its sample), for the final model
    and the corrected calibration."""
    k, dt = event.index, model.dt_s

    def build(ctx: CandidateContext) -> list[np.ndarray]:
        n = ctx.lin.m.shape[0]
        columns = []
        for axis in range(3):
            torque = np.zeros((n, 3))
            torque[k, axis] = 1.0 / dt
            columns.append(_torque_column(ctx, torque))
        for axis in range(3):
            acc = np.zeros((n, 3))
            acc[k, axis] = 1.0 / (ctx.model.mass_kg * dt)
            columns.append(_perturb(ctx, dacc=acc))
        return columns

    def inject(theta: np.ndarray, _model: NominalModel) -> dict[str, Any]:
        return {"name": "impulse", "time_s": event.time_s, "angular_momentum_n_m_s": list(theta[:3]),
                "linear_impulse_n_s": list(theta[3:6])}

    return Candidate(name="impulse", variant=f"t{event.time_s:.1f}",
                     params=("L_x", "L_y", "L_z", "p_x", "p_y", "p_z"), unit="N m s, N s", build=build,
                     inject=inject)
