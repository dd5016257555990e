"""A thruster lag and a delay fitted together, by their exact joint signature (stages 3 and 4).

The thrust under a delay and a lag together is not the sum of the thrust under each, and the data
fix their sum (the group delay) to a fraction of a millisecond but their split only to ~20 ms.
Fitted side by side, each signature exact only at the other's model value, a second-order residual
stays where the thrust changes (torque channels, 0.3-5 Hz). In the forward selection that residual
also hides the second of the pair: a delay fitted alone takes the whole group delay (0.2 s for a
73-ms delay and a 103-ms lag), and the lag's own signature, exact only at the model's delay, then
gains less than a GRS stamp offset does; the pair was named as two delays and the 0.3-1 Hz torque
gap stayed. So wherever a lag meets a delay, in the selection's score of the second of the two
and in the final fit, (delay, lag) are fitted together by a simplex over the exact channel change
``tau_act(D0 + delay, T0 + lag) - tau_act(D0, T0)`` (every other column refitted linearly),
started from the best of a few splits of the fitted group delay.

The fit band (below ``f_max``, 0.2 Hz) fixes the group delay; the split shows above it, where
the thrust changes. There the chain's response (:mod:`.dynamics`: per axis b1, b2 and a residual
delay, instrument calibration fitted above ``f_max``) absorbs a timing error to first order, so
the objective adds the torque channels' chi-square from the fit band's top to
:data:`HIGH_BAND_TOP_HZ` with that response projected out at every trial pair
(:class:`HighBand`; the other columns held at their fit, which the fit band fixes). On a 3-h
reference set (a 73-ms delay and a 103-ms lag) the fit band alone scores the pair against a
176-ms delay at delta chi2 57, the same as a GRS stamp offset that leaves a 0.3-1 Hz torque gap;
the high band gives the lag delta chi2 ~ 690 and the split within 4 ms of the truth. The high band
scores the selection only: the final fit refits every column linearly on the fit band, which would
move a high-band split along the ridge, so the final joint fit is on the fit band as well.
:func:`apply_joint_timing` then makes the lag's column its exact secant at the fitted lag and
the delay's its exact secant conditioned on that lag: the two sum exactly to the joint change at
the fitted pair.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import minimize

from taiji2_estimator_pkg.diagnosis.candidates import Candidate, NoiseCandidate
from taiji2_estimator_pkg.diagnosis.dynamics import response_columns
from taiji2_estimator_pkg.diagnosis.record import Record

__all__ = ["DELAY_FAMILIES", "HIGH_BAND_TOP_HZ", "LAG_FAMILY", "HighBand", "JointTiming", "apply_joint_timing",
           "fit_joint_timing", "high_band", "joint_partner", "score_joint_timing"]

DELAY_FAMILIES = ("actuation_delay", "grs_time_offset")
"""Families that delay the thrust against the GRS (the GRS stamp offset also moves the star tracker)."""

LAG_FAMILY = "thruster_response"

HIGH_BAND_TOP_HZ = 2.0
"""Top of the torque channels' band above the fit band that also scores a (delay, lag) pair [Hz]
(well below the readout chain's anti-alias roll-off, which the response fit absorbs)."""

_TORQUE = slice(3, 6)  # the torque channels of the 15 (.channels)
_RIDGE_LAGS_S = (0.0, 0.025, 0.05, 0.075, 0.1, 0.15, 0.2, 0.3)  # starting splits of the group delay [s]


@dataclass(frozen=True)
class JointTiming:
    """A (delay, lag) pair fitted jointly.

    Attributes
    ----------
    delay, lag : Candidate
        The delay-family candidate and the thruster-lag candidate.
    delay_s, lag_s : float
        Fitted extra delay and lag beyond the model's [s].
    chi2 : float
        Chi-square with their joint change fixed and the ``free`` columns refitted (plus the
        high band's, where it was scored).
    """

    delay: Candidate
    lag: Candidate
    delay_s: float
    lag_s: float
    chi2: float


@dataclass(frozen=True)
class HighBand:
    """The torque channels above the fit band, where a delay and a lag differ, with the chain's
    response (:mod:`.dynamics`: b1, b2 and a residual delay per axis, fitted there) projected out.

    Attributes
    ----------
    first, last : int
        DFT bins kept (``first..last``, above the fit band's ``k_max``).
    base : ndarray
        (K, 3) DFT (:func:`.spectral.dft` scaling) of the torque-channel residual of the current fit with
        the pair's columns added back (what the pair's change must explain), before the response.
    weight : ndarray
        (K, 3) ``sqrt(2 / S)`` (S the nominal marginal spectrum): chi2 = sum |weight Y|^2 per real degree
        of freedom.
    response : ndarray
        (3, 2K, 3) per axis an orthonormal basis of the weighted response columns (real and imaginary
        parts stacked), projected out of every residual.
    current : float
        chi2 of the current fit's residual there.
    """

    first: int
    last: int
    base: np.ndarray
    weight: np.ndarray
    response: np.ndarray
    current: float

    def chi2(self, change: np.ndarray) -> float:
        """chi2 of the base residual less an (n, 15) channel change, the response refitted."""
        return self._chi2(self.base - _spectrum(change[:, _TORQUE], self.first, self.last))

    def _chi2(self, residual: np.ndarray) -> float:
        total = 0.0
        for axis in range(3):
            y = self.weight[:, axis] * residual[:, axis]
            stacked = np.concatenate((y.real, y.imag))
            projection = self.response[axis].T @ stacked
            total += float(stacked @ stacked - projection @ projection)
        return total


def high_band(record: Record, names: Sequence[str], theta: np.ndarray, pair: tuple[Candidate, Candidate]
              ) -> HighBand | None:
    """The torque channels above the fit band for the fit ``(names, theta)``, the ``pair``'s columns added
    back; None when the record has no bins there."""
    n = record.n
    first = record.k_max + 1
    last = min(int(HIGH_BAND_TOP_HZ * n * record.model.dt_s), (n - 1) // 2)
    if last < first:
        return None
    residual = record.fitted_residual(names, theta)
    predicted = record.lin.m - residual[:, _TORQUE]
    weight = np.sqrt(2.0 / record.spectrum.marginal(np.arange(first, last + 1))[:, _TORQUE])
    response = np.empty((3, 2 * (last - first + 1), 3))
    for axis in range(3):
        x = weight[:, axis, None] * _spectrum(
            response_columns(predicted[:, axis], record.model.dt_s, record.lin.torque_edges), first, last)
        response[axis] = np.linalg.qr(np.concatenate((x.real, x.imag)))[0]
    spectrum = _spectrum(residual[:, _TORQUE], first, last)
    band = HighBand(first, last, spectrum, weight, response, 0.0)
    current = band._chi2(spectrum)
    position = {name: i for i, name in enumerate(names)}
    for candidate in pair:
        (name,) = candidate.column_names()
        if name in position and theta[position[name]] != 0.0:
            (column,) = record.time_columns(candidate)
            spectrum = spectrum + theta[position[name]] * _spectrum(column[:, _TORQUE], first, last)
    return HighBand(first, last, spectrum, weight, response, current)


def _spectrum(x: np.ndarray, first: int, last: int) -> np.ndarray:
    """Bins ``first..last`` of ``rfft(x, axis=0) / sqrt(n)``."""
    return np.fft.rfft(x, axis=0)[first:last + 1] / np.sqrt(x.shape[0])


def joint_partner(candidate: Candidate | NoiseCandidate, accepted: Sequence[Candidate | NoiseCandidate],
                  record: Record) -> tuple[Candidate, Candidate] | None:
    """The (delay, lag) pair ``candidate`` forms with an accepted variant, or None.

    A lag candidate pairs with the accepted delay of largest fitted magnitude; a delay candidate
    with the accepted lag while no delay is accepted. Neither may have a modelled onset (the joint
    signature is from the start) or lack an exact signature.
    """
    if not isinstance(candidate, Candidate) or candidate.exact is None or candidate.key in record.onsets:
        return None
    usable = [c for c in accepted if isinstance(c, Candidate) and c.exact is not None and c.key not in record.onsets]
    if candidate.name == LAG_FAMILY:
        delays = [c for c in usable if c.name in DELAY_FAMILIES]
        if not delays:
            return None
        return max(delays, key=lambda c: abs(record.secant.get(c.key, 0.0))), candidate
    if candidate.name in DELAY_FAMILIES:
        if any(isinstance(c, Candidate) and c.name in DELAY_FAMILIES for c in accepted):
            return None
        lag = next((c for c in usable if c.name == LAG_FAMILY), None)
        return None if lag is None else (candidate, lag)
    return None


def fit_joint_timing(record: Record, delay: Candidate, lag: Candidate, others: Sequence[str],
                     high: HighBand | None = None) -> JointTiming:
    """Fit (delay, lag) jointly by their exact change, the columns ``others`` (less theirs) refitted.

    Parameters
    ----------
    record : Record
        The fitting workspace; its current secants of ``delay`` and ``lag`` (0 where not fitted)
        give the group delay the starts split.
    delay, lag : Candidate
        A delay-family candidate and the lag candidate.
    others : sequence of str
        Columns refitted at each trial pair (the two candidates' own columns are dropped).
    high : HighBand, optional
        Adds the torque channels above the fit band to the objective (:func:`high_band`).
    """
    own = set(delay.column_names() + lag.column_names())
    free = [name for name in others if name not in own]
    t0 = record.model.time_constant_s
    group = record.secant.get(delay.key, 0.0) + record.secant.get(lag.key, 0.0)
    starts = [np.array([group - t, t]) for t in sorted({*_RIDGE_LAGS_S, record.secant.get(lag.key, 0.0)})
              if t + t0 >= 0.0]
    args = (record, delay, lag, free, high)
    start = min(starts, key=lambda x: _joint_chi2(x, *args))
    simplex = start + np.array([[0.0, 0.0], [0.01, 0.0], [-0.01, 0.01]])
    best = minimize(_joint_chi2, start, args=args, method="Nelder-Mead",
                    options={"initial_simplex": simplex, "xatol": 2e-5, "fatol": 1e-3, "maxfev": 120})
    return JointTiming(delay, lag, float(best.x[0]), max(float(best.x[1]), -t0), float(best.fun))


def score_joint_timing(record: Record, joint: JointTiming, others: Sequence[str], high: HighBand | None = None
                       ) -> JointTiming:
    """``joint`` with its chi2 at its fitted pair for the columns ``others`` now (not refitted: the
    selection fits a pair once, at its first step, and rescores it as other effects join)."""
    free = [name for name in others if name not in joint.delay.column_names() + joint.lag.column_names()]
    x = np.array([joint.delay_s, joint.lag_s])
    return replace(joint, chi2=_joint_chi2(x, record, joint.delay, joint.lag, free, high))


def apply_joint_timing(record: Record, joint: JointTiming) -> None:
    """Make the pair's columns their exact secants at the fitted pair (they sum to the joint change)."""
    delay_change, lag_change = _timing_changes(record, joint.delay, joint.lag, joint.delay_s, joint.lag_s)
    record.set_exact_secant(joint.lag, joint.lag_s, lag_change)
    record.set_exact_secant(joint.delay, joint.delay_s, delay_change)


def _timing_changes(record: Record, delay: Candidate, lag: Candidate, delay_s: float, lag_s: float
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The exact channel changes of (delay, lag): the lag's alone, the delay's at that lag."""
    ctx = record.ctx
    lag_s = max(lag_s, -record.model.time_constant_s)
    ctx.timing_base.clear()
    lag_change = lag.exact(ctx, lag_s)
    ctx.timing_base["time_constant_s"] = lag_s
    delay_change = delay.exact(ctx, delay_s)
    ctx.timing_base.clear()
    return delay_change, lag_change


def _joint_chi2(x: np.ndarray, record: Record, delay: Candidate, lag: Candidate, free: Sequence[str],
                high: HighBand | None) -> float:
    """chi2 with the joint change of (delay, lag) = ``x`` [s] and the ``free`` columns refitted
    (plus the high band's)."""
    delay_change, lag_change = _timing_changes(record, delay, lag, float(x[0]), float(x[1]))
    change = delay_change + lag_change
    return record.chi2_with_column(free, change) + (0.0 if high is None else high.chi2(change))
