"""A thruster lag and a delay fitted together, by their exact joint signature (stages 3 and 4).

The thrust under a delay and a lag together is not the sum of the thrust under each, and the data
fix their sum (the group delay) to a fraction of a millisecond but their split only to ~20 ms.
Fitted side by side, each signature exact only at the other's model value, a second-order residual
stays where the thrust changes (torque channels, 0.3-5 Hz). So wherever a lag meets a delay, in the
selection's score of the second of the two (:func:`joint_partner`) and in the final fit, (delay, lag)
are fitted together by a simplex over the exact channel change ``tau_act(D0 + delay, T0 + lag) -
tau_act(D0, T0)`` (every other column refitted linearly), started from the best of a few splits of
the fitted group delay. :func:`apply_joint_timing` then makes the lag's column its exact secant at the
fitted lag and the delay's its exact secant conditioned on that lag: the two sum exactly to the joint
change at the fitted pair.

Both fits use the fit band (below ``f_max``), where the split is weakly determined: a 73-ms delay with
a 103-ms lag against a 176-ms delay alone differ there by delta chi2 ~ 60 in 3 h, and a GRS stamp
offset beside the delay can gain as much (docs/diagnosis.md, "the torque channels above the fit band":
scoring the pair there too was tried and left out, because the final linear refit of the two nearly
collinear columns on the fit band undoes a split set above it).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import minimize

from taiji2_estimator_pkg.diagnosis.candidates import Candidate, NoiseCandidate
from taiji2_estimator_pkg.diagnosis.record import Record

__all__ = ["DELAY_FAMILIES", "LAG_FAMILY", "JointTiming", "apply_joint_timing", "fit_joint_timing", "joint_partner",
           "score_joint_timing"]

DELAY_FAMILIES = ("actuation_delay", "grs_time_offset")
"""Families that delay the thrust against the GRS (the GRS stamp offset also moves the star tracker)."""

LAG_FAMILY = "thruster_response"

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
        Chi-square with their joint change fixed and the ``free`` columns refitted.
    """

    delay: Candidate
    lag: Candidate
    delay_s: float
    lag_s: float
    chi2: float


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


def fit_joint_timing(record: Record, delay: Candidate, lag: Candidate, others: Sequence[str]) -> JointTiming:
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
    """
    own = set(delay.column_names() + lag.column_names())
    free = [name for name in others if name not in own]
    t0 = record.model.time_constant_s
    group = record.secant.get(delay.key, 0.0) + record.secant.get(lag.key, 0.0)
    starts = [np.array([group - t, t]) for t in sorted({*_RIDGE_LAGS_S, record.secant.get(lag.key, 0.0)})
              if t + t0 >= 0.0]
    args = (record, delay, lag, free)
    start = min(starts, key=lambda x: _joint_chi2(x, *args))
    simplex = start + np.array([[0.0, 0.0], [0.01, 0.0], [-0.01, 0.01]])
    best = minimize(_joint_chi2, start, args=args, method="Nelder-Mead",
                    options={"initial_simplex": simplex, "xatol": 2e-5, "fatol": 1e-3, "maxfev": 120})
    return JointTiming(delay, lag, float(best.x[0]), max(float(best.x[1]), -t0), float(best.fun))


def score_joint_timing(record: Record, joint: JointTiming, others: Sequence[str]) -> JointTiming:
    """``joint`` with its chi2 at its fitted pair for the columns ``others`` now (not refitted: the
    selection fits a pair once, at its first step, and rescores it as other effects join)."""
    free = [name for name in others if name not in joint.delay.column_names() + joint.lag.column_names()]
    x = np.array([joint.delay_s, joint.lag_s])
    return replace(joint, chi2=_joint_chi2(x, record, joint.delay, joint.lag, free))


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


def _joint_chi2(x: np.ndarray, record: Record, delay: Candidate, lag: Candidate, free: Sequence[str]) -> float:
    """chi2 with the joint change of (delay, lag) = ``x`` [s] and the ``free`` columns refitted."""
    delay_change, lag_change = _timing_changes(record, delay, lag, float(x[0]), float(x[1]))
    return record.chi2_with_column(free, delay_change + lag_change)
