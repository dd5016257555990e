"""Timing conventions of the data and the actuation: what a stamp means, and when a command acts.

Four numbers, all in seconds, define how the stamps of the raw data relate to the physics
(:class:`~.config_schema.TimingConfig`, section ``timing`` of a layout):

- ``grs_stamp`` (delta_g): a GRS sample is the mean acceleration over an interval of 1/fs; its stamp
  is the end of that interval plus delta_g (``end``: 0, ``midpoint``: -dt/2, ``start``: -dt);
- ``star_tracker_stamp_offset_s`` (epsilon): the star tracker stamped t read the attitude at
  t - epsilon;
- ``actuation_latency_s`` (L): the thrusters act on the command stamped t_k from t_k + L on;
- ``thruster_time_constant_s`` (T): first-order response of the thrust, T u' = c(t - L) - u.

One time shift of everything is unobservable, so the physics only sees two delays and the lag:
a GRS stamp late by delta_g is the same data as the physics delayed by delta_g (an extra actuation
delay) with the star tracker stamped delta_g early. :attr:`~.config_schema.TimingConfig.reduced` gives that
reduction, ``(D, e, T) = (L + delta_g, epsilon - delta_g, T)``, which both the simulator and the
diagnosis use.

:func:`actuation_weights` gives the exact mean, over each GRS integration interval, of the thrust
produced by a zero-order-hold command sequence delayed by D and lagged by T: a short FIR filter
on the command sequence (two taps for a pure fractional delay: the interval straddles two
commands), exact for any real D of either sign (a negative D needs later commands).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["GRS_STAMP_CONVENTIONS", "actuated_commands", "actuation_weights", "apply_actuation", "grs_stamp_offset_s"]

GRS_STAMP_CONVENTIONS = {"end": 0.0, "midpoint": -0.5, "start": -1.0}
"""GRS stamp conventions: stamp minus the end of the integration interval, in samples."""

# the lagged step response has converged to 1 within rounding after this many time constants
_LAG_TAIL_TIME_CONSTANTS = 40.0


def grs_stamp_offset_s(value: float | str, dt_s: float) -> float:
    """Stamp offset delta_g [s] of a GRS convention name (``end``, ``midpoint``, ``start``) or a number [s]."""
    if isinstance(value, str):
        if value not in GRS_STAMP_CONVENTIONS:
            raise ValueError(f"GRS stamp convention {value!r}: use one of {', '.join(GRS_STAMP_CONVENTIONS)} "
                             "or a number of seconds")
        return GRS_STAMP_CONVENTIONS[value] * dt_s
    return float(value)


def _integrated_step(x: np.ndarray, time_constant_s: float) -> np.ndarray:
    """R(x) = int_0^x r(s) ds of the unit step response r (0 before the step)."""
    x = np.maximum(x, 0.0)
    if time_constant_s <= 0.0:
        return x
    return x - time_constant_s * -np.expm1(-x / time_constant_s)


def actuation_weights(delay_s: float, time_constant_s: float, dt_s: float) -> tuple[int, np.ndarray]:
    """FIR weights from commands to the mean thrust over each sample interval.

    The command c_j is held over (t_j, t_j + dt]; the thrust is c(t - D) through a first-order lag T;
    the mean thrust over (t_k, t_k + dt] is ``sum_m w_m c_{k - m}`` with m from ``m_first`` on.

    Parameters
    ----------
    delay_s : float
        D [s], any sign.
    time_constant_s : float
        T [s] (>= 0; 0 = instantaneous).
    dt_s : float
        Sample interval [s].

    Returns
    -------
    m_first : int
        Lag of the first weight (negative when D < 0: later commands contribute).
    weights : numpy.ndarray
        w_m, summing to 1.
    """
    if not (math.isfinite(delay_s) and math.isfinite(time_constant_s) and time_constant_s >= 0.0 and dt_s > 0.0):
        raise ValueError(f"actuation timing: delay {delay_s} s, time constant {time_constant_s} s (must be >= 0), "
                         f"dt {dt_s} s")
    m_first = math.floor(delay_s / dt_s) - 1
    m_last = math.ceil((delay_s + _LAG_TAIL_TIME_CONSTANTS * time_constant_s) / dt_s) + 1
    m = np.arange(m_first - 1, m_last + 1, dtype=np.float64)
    # step response seen by the mean over (t_k, t_k + dt] of a unit step at t_{k-m} + D
    h = (_integrated_step((m + 1.0) * dt_s - delay_s, time_constant_s)
         - _integrated_step(m * dt_s - delay_s, time_constant_s)) / dt_s
    weights = np.diff(h)
    weights[-1] += 1.0 - float(np.sum(weights))  # the truncated tail (< 1e-17) to the last tap
    return m_first, weights


def actuated_commands(commands: ArrayLike, delay_s: float, time_constant_s: float, dt_s: float,
                      before: ArrayLike | None = None) -> np.ndarray:
    """Mean thrust over each sample interval for a command sequence (batch; :func:`actuation_weights`).

    Parameters
    ----------
    commands : array_like
        (n, k) commands c_0 .. c_{n-1}, c_j held over (t_j, t_j + dt].
    delay_s, time_constant_s, dt_s : float
        See :func:`actuation_weights`.
    before : array_like, optional
        (k,) command before c_0 (default zero: the thrusters were idle). After c_{n-1} the last
        command is held.

    Returns
    -------
    numpy.ndarray
        (n, k) mean thrust over (t_k, t_k + dt].
    """
    c = np.asarray(commands, dtype=np.float64)
    if c.ndim != 2:
        raise ValueError(f"commands: expected (n, k), got shape {c.shape}")
    n = c.shape[0]
    m_first, weights = actuation_weights(delay_s, time_constant_s, dt_s)
    if n == 0:
        return c.copy()
    m_last = m_first + weights.size - 1
    head = max(m_last, 0)  # commands needed before c_0
    tail = max(-m_first, 0)  # commands needed after c_{n-1}
    start = np.zeros(c.shape[1]) if before is None else np.asarray(before, dtype=np.float64)
    padded = np.concatenate([np.broadcast_to(start, (head, c.shape[1])), c,
                             np.broadcast_to(c[-1], (tail, c.shape[1]))])
    return apply_actuation(padded, head, n, m_first, weights)


def apply_actuation(padded: np.ndarray, head: int, count: int, m_first: int, weights: np.ndarray) -> np.ndarray:
    """``out_k = sum_m w_m c_{k - m}`` for k < count, c_k = ``padded[head + k]`` (the padding holds the
    commands before and after: at least ``m_first + len(weights) - 1`` rows before, ``-m_first`` after)."""
    # out_k = (padded * w)[head - m_first + k], the full convolution (C, one pass per column: 4x faster than a
    # sum of shifted copies for the ~50 taps of a 0.13-s lag at 10 Hz)
    first = head - m_first
    out = np.empty((count, padded.shape[1]))
    for column in range(padded.shape[1]):
        out[:, column] = np.convolve(padded[:, column], weights)[first: first + count]
    return out
