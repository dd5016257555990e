"""The nominal model the diagnosis compares the data with: layout, nominal parameters, noise budget.

Everything comes from a simulator layout (:class:`taiji2_model.config.SimConfig`, loaded
with ``load_config("type1" | "type2" | path)``): the nominal model is the simulator without any
catalog effect. Per-sample variances follow the simulator's discretisation exactly (white noise of
one-sided ASD S at fs has variance ``S^2 fs / 2``; SRP is an exact AR(1)), so that the channel
noise spectra of :mod:`.spectral` are exact and significance is honest.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from taiji2_model.config import SimConfig
from taiji2_model.frames import crf_to_tmrf
from taiji2_model.noise import srp_ou_parameters

__all__ = ["ANGULAR_TO_LINEAR", "NominalModel"]

ANGULAR_TO_LINEAR = (1, 2, 0)
"""Linear readout sharing the electrode pair of angular readout phi, theta, psi: y, z, x."""


@dataclass(frozen=True, eq=False)
class NominalModel:
    """Nominal model of the experiment (no truth: what the calibration team believes).

    Attributes
    ----------
    sample_rate_hz : float
        fs [Hz].
    inertia_kg_m2, inertia_inv : numpy.ndarray
        (3, 3) J [kg m^2] and its inverse.
    mass_kg : float
        Spacecraft mass M [kg].
    c_tmrf : numpy.ndarray
        (2, 3, 3) C_i (CRF -> TMRF_i).
    g_angular : numpy.ndarray
        (2, 3) nominal (G_Pphi, G_Ptheta, G_Ppsi) per GRS [rad s^-2 V^-1].
    ratio_m : float
        r = G_lin / G_ang [m] (the paper's consistent conversion).
    com_offset_m : numpy.ndarray
        (2, 3) nominal d_i, CRF [m].
    maneuver_period_s : float
        Square-wave period [s].
    var_st : numpy.ndarray
        (3,) star-tracker error variance per sample [rad^2].
    var_torque : numpy.ndarray
        (3,) thruster torque noise variance per step [N^2 m^2].
    var_force_acc : numpy.ndarray
        (3,) thruster force noise as spacecraft acceleration, per step [m^2 s^-4].
    srp_decay : float
        AR(1) coefficient of the SRP acceleration per step.
    var_srp_innovation : numpy.ndarray
        (3,) SRP innovation variance per step [m^2 s^-4].
    var_angular : numpy.ndarray
        (2, 3) angular readout noise (LFS rotational + voltage) per sample, TMRF [rad^2 s^-4].
    var_linear : numpy.ndarray
        (2, 3) linear readout noise (LFS translational + TM environment + voltage), TMRF [m^2 s^-4].
    layout : str
        Layout name.
    delay_s : float
        Command-to-GRS delay D of the data's timing conventions [s] (layout section ``timing``,
        reduced: actuation latency plus GRS stamp offset; :mod:`taiji2_model.timing`).
    st_offset_s : float
        Star-tracker stamp offset against the GRS e [s] (the star tracker stamped t read the
        attitude at t - e).
    time_constant_s : float
        First-order thruster response T [s].
    effects : tuple of dict
        Known catalog effects of an extended nominal model (the layout's ``effects`` section;
        :mod:`.extended`).
    """

    sample_rate_hz: float
    inertia_kg_m2: np.ndarray
    inertia_inv: np.ndarray
    mass_kg: float
    c_tmrf: np.ndarray
    g_angular: np.ndarray
    ratio_m: float
    com_offset_m: np.ndarray
    maneuver_period_s: float
    var_st: np.ndarray
    var_torque: np.ndarray
    var_force_acc: np.ndarray
    srp_decay: float
    var_srp_innovation: np.ndarray
    var_angular: np.ndarray
    var_linear: np.ndarray
    layout: str
    delay_s: float = 0.0
    st_offset_s: float = 0.0
    time_constant_s: float = 0.0
    effects: tuple = ()

    @property
    def dt_s(self) -> float:
        """1 / fs [s]."""
        return 1.0 / self.sample_rate_hz

    @property
    def p_crf(self) -> np.ndarray:
        """(2, 3, 3) C_i^T (TMRF_i -> CRF)."""
        return np.transpose(self.c_tmrf, (0, 2, 1))

    def g_linear(self, g_angular: np.ndarray | None = None) -> np.ndarray:
        """(2, 3) (G_Px, G_Py, G_Pz) = r (G_Ppsi, G_Pphi, G_Ptheta) [m s^-2 V^-1]."""
        angular = self.g_angular if g_angular is None else np.asarray(g_angular)
        return self.ratio_m * angular[..., [2, 0, 1]]

    @classmethod
    def from_config(cls, config: SimConfig) -> NominalModel:
        """Nominal model of a simulator layout.

        Parameters
        ----------
        config : SimConfig
            Layout (``load_config``); disabled noise sources get zero variance.

        Returns
        -------
        NominalModel
        """
        if not isinstance(config, SimConfig):
            raise TypeError(f"config: expected SimConfig, got {type(config).__name__}")
        fs = config.sample_rate_hz
        noise = config.noise
        half_fs = 0.5 * fs

        def white(source: object) -> np.ndarray:
            if not source.enabled:  # type: ignore[attr-defined]
                return np.zeros(3)
            return np.asarray(source.asd, dtype=np.float64) ** 2 * half_fs  # type: ignore[attr-defined]

        sensors = config.grs.sensors
        g_angular = np.array([s.angular_scale_factors for s in sensors], dtype=np.float64)
        g_linear_true = np.array([s.linear_scale_factors for s in sensors], dtype=np.float64)
        ratio = config.grs.linear_to_angular_ratio_m
        var_voltage_linear = np.zeros((2, 3))
        var_voltage_angular = np.zeros((2, 3))
        if noise.grs_voltage.enabled:
            s2 = noise.grs_voltage.linear_equivalent_asd_m_s2_rthz ** 2 * half_fs
            var_voltage_linear[:] = s2
            # a channel has variance S^2 fs/2 / (2 G_lin^2): a difference pair 2x that, times G_ang^2
            ratio_sq = (g_angular[:, [2, 0, 1]] / g_linear_true) ** 2  # per electrode pair x, y, z
            var_voltage_angular[:] = (s2 * ratio_sq)[:, [1, 2, 0]]  # to phi (y), theta (z), psi (x)
        lfs_rot = white(noise.lfs_rotational)
        lfs_trans = white(noise.lfs_translational)
        environment = white(noise.tm_environment)
        srp = srp_ou_parameters(noise.srp, fs)
        var_st = (np.asarray(noise.star_tracker.sigma_rad, dtype=np.float64) ** 2 if noise.star_tracker.enabled
                  else np.zeros(3))
        inertia = np.array(config.spacecraft.inertia_kg_m2, dtype=np.float64)
        delay_s, st_offset_s, time_constant_s = config.timing.reduced
        return cls(
            sample_rate_hz=float(fs),
            inertia_kg_m2=inertia,
            inertia_inv=np.linalg.inv(inertia),
            mass_kg=float(config.spacecraft.mass_kg),
            c_tmrf=np.stack([crf_to_tmrf(s.grs_id, config.grs.alpha_rad) for s in sensors]),
            g_angular=g_angular,
            ratio_m=float(ratio),
            com_offset_m=np.array([s.com_offset_m for s in sensors], dtype=np.float64),
            maneuver_period_s=float(config.maneuver.period_s),
            var_st=var_st,
            var_torque=white(noise.thruster_torque),
            var_force_acc=white(noise.thruster_force) / config.spacecraft.mass_kg ** 2,
            srp_decay=float(srp.decay) if noise.srp.enabled else 0.0,
            var_srp_innovation=np.full(3, srp.innovation_std ** 2 if noise.srp.enabled else 0.0),
            var_angular=lfs_rot[None, :] + var_voltage_angular,
            var_linear=(lfs_trans + environment)[None, :] + var_voltage_linear,
            layout=str(config.layout),
            delay_s=float(delay_s),
            st_offset_s=float(st_offset_s),
            time_constant_s=float(time_constant_s),
            effects=tuple(getattr(config, "effects", ())),
        )

    def summary(self) -> dict[str, object]:
        """Plain dict of the nominal values used (for the report)."""
        return {
            "layout": self.layout,
            "sample_rate_hz": self.sample_rate_hz,
            "inertia_kg_m2": self.inertia_kg_m2.tolist(),
            "mass_kg": self.mass_kg,
            "g_angular": self.g_angular.tolist(),
            "ratio_m": self.ratio_m,
            "com_offset_m": self.com_offset_m.tolist(),
            "maneuver_period_s": self.maneuver_period_s,
            "star_tracker_sigma_rad": np.sqrt(self.var_st).tolist(),
            "thruster_torque_asd_n_m_rthz": np.sqrt(self.var_torque / (0.5 * self.sample_rate_hz)).tolist(),
            "timing": {"delay_s": self.delay_s, "st_offset_s": self.st_offset_s,
                       "time_constant_s": self.time_constant_s},
            "effects": [dict(effect) for effect in self.effects],
            "srp_decay_per_step": self.srp_decay,
            "srp_corner_hz": (-math.log(self.srp_decay) * self.sample_rate_hz / (2 * math.pi)
                              if 0.0 < self.srp_decay < 1.0 else None),
        }
