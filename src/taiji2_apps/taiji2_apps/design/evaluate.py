"""Evaluate a candidate maneuver: CRLB / requirement of the 12 parameters, range, thrust, attitude.

The bound is :func:`taiji2_estimator_pkg.core.crlb.crlb`: its default, the full bound of G and d
estimated jointly from every channel of both GRS and the star tracker (what the default estimators
reach), noise budget of the layout, on the noise-free simulated response of the candidate. The
fast path exploits stationarity: for a periodic maneuver the information grows linearly with the
record length, so the covariance over T is the covariance over a window W of a whole number of
periods times W / T. What this neglects is the end effect (diffuse initial
attitude/rate, bias and trend nuisances), which makes the window bound *larger* by O(P / W); with
W >= 1000 s it is 1-2 % at the paper's preset (tested against the whole-duration bound). Every
reported number of a final design is the whole-duration bound.

Usage is taken from the noise-free simulation of the whole duration (``SimOutput`` truth):
peak maneuver-induced linear acceleration per GRS and TMRF axis (the range constraint adds k sigma
of the readout noise of each axis to it, :attr:`DesignProblem.noise_fraction`),
peak thrust per axis ``|tau| / L``, and peak small-angle attitude excursion per CRF axis.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from taiji2_estimator_pkg.core.crlb import CrlbResult, crlb
from taiji2_estimator_pkg.core.instrument import InstrumentModel

__all__ = ["D_REQUIREMENT_M", "G_REQUIREMENT_RELATIVE", "PARAMETER_NAMES", "DesignProblem", "Usage",
           "requirement_ratios"]

G_REQUIREMENT_RELATIVE = 3e-3
"""Scale-factor requirement: 0.3 % relative (1 sigma)."""
D_REQUIREMENT_M = 100e-6
"""c.m.-offset requirement: 100 um (1 sigma)."""
_G_NAMES = ("G_Pphi", "G_Ptheta", "G_Ppsi")
_D_NAMES = ("d_x", "d_y", "d_z")
PARAMETER_NAMES = tuple(f"grs{g}.{n}" for g in (1, 2) for n in (*_G_NAMES, *_D_NAMES))
"""The 12 designed parameters, in the order of every ratio vector."""
MIN_WINDOW_S = 1000.0
"""Shortest window of the fast bound [s] (end effect <= ~2 %)."""


def requirement_ratios(result: CrlbResult) -> np.ndarray:
    """(12,) CRLB / requirement in :data:`PARAMETER_NAMES` order (G relative / 0.3 %, d / 100 um)."""
    g = result.scale_factor_relative_sigma / G_REQUIREMENT_RELATIVE
    d = result.com_offset_sigma / D_REQUIREMENT_M
    return np.concatenate([np.concatenate((g[3 * i:3 * i + 3], d[3 * i:3 * i + 3])) for i in range(2)])


@dataclass(frozen=True)
class Usage:
    """Resource usage of a maneuver over its duration.

    Attributes
    ----------
    range_fraction : numpy.ndarray
        (2, 3) peak |maneuver-induced linear acceleration| / range per GRS, TMRF axis.
    thrust_n : numpy.ndarray
        (3,) peak thrust per CRF axis [N].
    attitude_rad : numpy.ndarray
        (3,) peak |small-angle attitude| per CRF axis [rad].
    """

    range_fraction: np.ndarray
    thrust_n: np.ndarray
    attitude_rad: np.ndarray

    def to_dict(self) -> dict[str, Any]:
        """Plain dict."""
        return {"range_fraction": self.range_fraction.tolist(), "thrust_peak_n": self.thrust_n.tolist(),
                "attitude_peak_rad": self.attitude_rad.tolist()}


class DesignProblem:
    """One layout: its noise budget, true G and d, thrusters, and the noise-free simulator.

    Parameters
    ----------
    layout : str, path or mapping
        Built-in layout name or simulator config.
    """

    def __init__(self, layout: Any) -> None:
        from taiji2_model.config import NOISE_SOURCE_NAMES, load_config  # optional dependency

        self.config = load_config(layout)
        self.quiet = load_config(layout, overrides={f"noise.{n}.enabled": False for n in NOISE_SOURCE_NAMES})
        self.instrument = InstrumentModel.from_layout(self.config)
        sensors = {s.grs_id: s for s in self.config.grs.sensors}
        self.grs_ids = (1, 2)
        self.scale_factors = {g: sensors[g].angular_scale_factors for g in self.grs_ids}
        self.com_offsets = {g: sensors[g].com_offset_m for g in self.grs_ids}
        thrusters = self.config.thrusters
        self.lever_arm_m = float(thrusters.lever_arm_m)
        self.min_thrust_n = float(thrusters.min_thrust_n)
        self.max_thrust_n = float(thrusters.max_thrust_n)
        self.range_m_s2 = float(self.config.grs.range_m_s2)
        self.dt_s = float(self.config.dt_s)
        from taiji2_model.noise import linear_readout_noise_std_m_s2

        #: (2, 3) per-sample 1-sigma of the noise on each linear readout (every enabled source) / range
        self.noise_fraction = linear_readout_noise_std_m_s2(self.config) / self.range_m_s2

    def paper_maneuver(self, duration_s: float) -> Any:
        """The layout's preset square wave over ``duration_s``."""
        from taiji2_model.maneuver import SquareWaveManeuver

        m = self.config.maneuver
        return SquareWaveManeuver(m.period_s, m.amplitude_n_m, m.phase_s, 0.0, duration_s)

    def simulate(self, maneuver: Any, duration_s: float) -> Any:
        """Noise-free batch response (SimOutput) over ``[0, duration)``."""
        from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch

        n = max(1, round(duration_s / self.dt_s))
        return simulate_batch(self.quiet, 0, maneuver_torque_commands(self.quiet, n, 0.0, maneuver=maneuver))

    def usage(self, maneuver: Any, duration_s: float, response: Any = None) -> Usage:
        """Range, thrust and attitude usage over the duration (simulated unless ``response`` given)."""
        out = self.simulate(maneuver, duration_s) if response is None else response
        range_fraction = np.max(np.abs(out.truth.grs_linear_maneuver), axis=0) / self.range_m_s2
        thrust_n = np.max(np.abs(out.truth.torque_command_n_m), axis=0) / self.lever_arm_m
        q = out.truth.quat_xyzw
        # small-angle attitude theta = 2 q_xyz sign(q_w)
        attitude = 2.0 * q[:, :3] * np.sign(np.where(q[:, 3:] == 0.0, 1.0, q[:, 3:]))
        return Usage(range_fraction, thrust_n, np.max(np.abs(attitude), axis=0))

    def bound(self, maneuver: Any, duration_s: float, period_s: float | None = None,
              fast: bool = False) -> CrlbResult:
        """CRLB of G and d for the maneuver over ``duration_s``.

        Parameters
        ----------
        maneuver : object
            Any maneuver family.
        duration_s : float
            Record length T [s].
        period_s : float, optional
            Repetition period of the maneuver (needed for ``fast``).
        fast : bool
            Window of whole periods (>= :data:`MIN_WINDOW_S`) scaled by W / T (see module doc).
        """
        window_s = duration_s
        if fast and period_s is not None:
            window_s = min(duration_s, period_s * np.ceil(MIN_WINDOW_S / period_s))
        out = self.simulate(maneuver, window_s)
        result = crlb(self.instrument, out.t_s, out.truth.omega_dot_rad_s2, out.truth.omega_rad_s, self.grs_ids,
                      self.scale_factors, self.com_offsets)
        if window_s == duration_s:
            return result
        # information grows as T for a stationary (periodic) maneuver: Cov(T) = Cov(W) W / T
        return result.scaled(window_s / duration_s, duration_s)

    def ratios(self, maneuver: Any, duration_s: float, period_s: float | None = None,
               fast: bool = False) -> np.ndarray:
        """(12,) CRLB / requirement (see :meth:`bound`)."""
        return requirement_ratios(self.bound(maneuver, duration_s, period_s, fast))


def duration_meeting(ratios: Sequence[float], duration_s: float) -> np.ndarray:
    """Duration at which each CRLB reaches its requirement: ``T ratio^2`` (CRLB ~ 1 / sqrt(T)) [s]."""
    return duration_s * np.asarray(ratios, dtype=np.float64) ** 2
