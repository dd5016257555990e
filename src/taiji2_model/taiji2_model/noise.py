"""Seeded noise streams, one independent random stream per named source.

Each source draws from its own generator, derived from ``(seed, source name)`` through
:class:`numpy.random.SeedSequence`, so that switching one source off, or adding a new one, leaves
the draws of all the others unchanged. Draws are taken in time order with the step index as the
leading axis, so that n calls with one step each give bitwise the same numbers as one call with
n steps (the streaming/batch equivalence of the simulator rests on this).

White noise of one-sided ASD S sampled at fs has per-sample standard deviation ``S sqrt(fs/2)``
(its power spread flat over 0..fs/2).
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.signal import lfilter

from taiji2_model.config_schema import NOISE_SOURCE_NAMES, SimConfig, SrpNoiseConfig

__all__ = [
    "NoiseDraws",
    "NoiseStreams",
    "OrnsteinUhlenbeckParameters",
    "linear_readout_noise_std_m_s2",
    "noise_rng",
    "srp_asd_m_s2_rthz",
    "srp_ou_parameters",
    "voltage_channel_std_v",
    "white_noise_std",
]


def noise_rng(seed: int, source_name: str) -> np.random.Generator:
    """Independent generator of one named source.

    Parameters
    ----------
    seed : int
        Run seed (non-negative).
    source_name : str
        Stable source name; its CRC-32 is the SeedSequence spawn key, so the stream does not
        depend on which other sources exist.

    Returns
    -------
    numpy.random.Generator
        PCG64 generator.
    """
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ValueError(f"seed: must be a non-negative integer, got {seed!r}")
    key = zlib.crc32(source_name.encode("utf-8"))
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence(int(seed), spawn_key=(key,))))


def white_noise_std(asd: ArrayLike, sample_rate_hz: float) -> np.ndarray:
    """Per-sample standard deviation of band-limited white noise.

    Parameters
    ----------
    asd : array_like
        One-sided amplitude spectral density [unit Hz^-1/2].
    sample_rate_hz : float
        Sample rate fs [Hz].

    Returns
    -------
    numpy.ndarray
        ``asd sqrt(fs / 2)`` [unit].
    """
    return np.asarray(asd, dtype=np.float64) * math.sqrt(0.5 * sample_rate_hz)


def srp_asd_m_s2_rthz(frequency_hz: ArrayLike, config: SrpNoiseConfig) -> np.ndarray:
    """Specified SRP one-sided ASD ``A f_ref / sqrt(f^2 + f_c^2)`` [m s^-2 Hz^-1/2]."""
    f = np.asarray(frequency_hz, dtype=np.float64)
    return config.asd_at_f_ref_m_s2_rthz * config.f_ref_hz / np.sqrt(f * f + config.f_corner_hz**2)


@dataclass(frozen=True)
class OrnsteinUhlenbeckParameters:
    """Exact AR(1) discretisation of an Ornstein-Uhlenbeck process.

    Attributes
    ----------
    decay : float
        ``phi = exp(-2 pi f_c dt)``.
    innovation_std : float
        ``sigma sqrt(1 - phi^2)`` [m s^-2].
    stationary_std : float
        sigma [m s^-2]; one-sided PSD ``(sigma^2 2 f_c / pi) / (f^2 + f_c^2)``.
    """

    decay: float
    innovation_std: float
    stationary_std: float


def srp_ou_parameters(config: SrpNoiseConfig, sample_rate_hz: float) -> OrnsteinUhlenbeckParameters:
    """AR(1) parameters whose continuous process has the specified SRP ASD.

    The OU process with correlation ``sigma^2 exp(-lambda |tau|)``, ``lambda = 2 pi f_c``, has the
    one-sided PSD ``sigma^2 lambda / pi^2 / (f^2 + f_c^2)``; equating it to
    ``A^2 f_ref^2 / (f^2 + f_c^2)`` gives ``sigma^2 = A^2 f_ref^2 pi / (2 f_c)``. Sampling at dt is
    exact: ``x_{k+1} = phi x_k + sigma sqrt(1 - phi^2) e_k``.
    """
    decay_rate_per_s = 2.0 * math.pi * config.f_corner_hz
    dt_s = 1.0 / sample_rate_hz
    stationary_std = config.asd_at_f_ref_m_s2_rthz * config.f_ref_hz * math.sqrt(
        math.pi / (2.0 * config.f_corner_hz))
    # 1 - phi^2 by expm1: phi is within 1e-5 of 1 at the nominal values
    innovation_std = stationary_std * math.sqrt(-math.expm1(-2.0 * decay_rate_per_s * dt_s))
    return OrnsteinUhlenbeckParameters(math.exp(-decay_rate_per_s * dt_s), innovation_std, stationary_std)


@dataclass(frozen=True)
class NoiseDraws:
    """Noise of n consecutive steps (zeros for a disabled source).

    Attributes
    ----------
    thruster_torque_n_m : numpy.ndarray
        (n, 3) torque noise in CRF, held over each step [N m].
    thruster_force_n : numpy.ndarray
        (n, 3) force noise in CRF, held over each step [N].
    srp_m_s2 : numpy.ndarray
        (n, 3) SRP acceleration in CRF at each step start, held over the step [m s^-2].
    lfs_translational_m_s2 : numpy.ndarray
        (n, 2, 3) per GRS, TMRF [m s^-2].
    lfs_rotational_rad_s2 : numpy.ndarray
        (n, 2, 3) per GRS, TMRF (phi, theta, psi) [rad s^-2].
    tm_environment_m_s2 : numpy.ndarray
        (n, 2, 3) per GRS, TMRF [m s^-2].
    grs_voltage_v : numpy.ndarray
        (n, 2, 6) per GRS, channels vx1, vx2, vy1, vy2, vz1, vz2 [V].
    star_tracker_rad : numpy.ndarray
        (n, 3) small-angle error about CRF X, Y, Z [rad].
    """

    thruster_torque_n_m: np.ndarray
    thruster_force_n: np.ndarray
    srp_m_s2: np.ndarray
    lfs_translational_m_s2: np.ndarray
    lfs_rotational_rad_s2: np.ndarray
    tm_environment_m_s2: np.ndarray
    grs_voltage_v: np.ndarray
    star_tracker_rad: np.ndarray


#: Steps per row in which the white draws are scaled by their standard deviations.
_SCALE_STEPS = 512
#: Per-step shape of each white source's draws.
_SOURCE_SHAPES = {"thruster_torque": (3,), "thruster_force": (3,), "lfs_translational": (2, 3),
                  "lfs_rotational": (2, 3), "tm_environment": (2, 3), "grs_voltage": (2, 6), "star_tracker": (3,)}


class NoiseStreams:
    """All noise sources of one run, drawn step-block by step-block.

    Parameters
    ----------
    config : SimConfig
        Noise amplitudes, switches, sample rate, true linear scale factors (for the voltage noise).
    seed : int
        Run seed.
    """

    def __init__(self, config: SimConfig, seed: int) -> None:
        noise = config.noise
        fs = config.sample_rate_hz
        self._rngs = {name: noise_rng(seed, name) for name in NOISE_SOURCE_NAMES}
        self._enabled = {name: bool(getattr(noise, name).enabled) for name in NOISE_SOURCE_NAMES}
        self._std = {
            "thruster_torque": white_noise_std(noise.thruster_torque.asd, fs),
            "thruster_force": white_noise_std(noise.thruster_force.asd, fs),
            "lfs_translational": white_noise_std(noise.lfs_translational.asd, fs),
            "lfs_rotational": white_noise_std(noise.lfs_rotational.asd, fs),
            "tm_environment": white_noise_std(noise.tm_environment.asd, fs),
            "star_tracker": np.asarray(noise.star_tracker.sigma_rad, dtype=np.float64),
            "grs_voltage": np.stack([
                voltage_channel_std_v(noise.grs_voltage.linear_equivalent_asd_m_s2_rthz,
                                      sensor.linear_scale_factors, fs)
                for sensor in config.grs.sensors
            ]),
        }
        # each source's standard deviations laid out over _SCALE_STEPS steps: the draws are scaled
        # in rows of that many steps (a per-step pattern of 3 or 6 values broadcast over the draws
        # would make numpy loop once per step; the products are the same)
        self._std_rows = {name: np.tile(np.broadcast_to(std, _SOURCE_SHAPES[name]).ravel(), _SCALE_STEPS)
                          for name, std in self._std.items()}
        self.srp_parameters = srp_ou_parameters(noise.srp, fs)
        # stationary start: the first SRP draw of the stream is the initial state
        self._srp_state = np.zeros(3)
        if self._enabled["srp"]:
            self._srp_state = self.srp_parameters.stationary_std * self._rngs["srp"].standard_normal(3)

    def enabled(self, source_name: str) -> bool:
        """Whether a source is switched on."""
        return self._enabled[source_name]

    def draw_source(self, source_name: str, n: int, out: np.ndarray | None = None) -> np.ndarray:
        """The next n steps of one source (the field of :meth:`draw` of that name, shape (n, ...)).

        Each source has its own generator, so drawing sources one by one, in any order and in any
        blocking of the steps, gives bitwise the numbers of :meth:`draw`. ``out``, a C-contiguous
        array of that shape (e.g. the simulator's output array that the noise is added to),
        receives the draws instead of a new array.
        """
        shape = (n, 3) if source_name == "srp" else (n, *_SOURCE_SHAPES[source_name])
        if out is not None and (out.shape != shape or not out.flags.c_contiguous):
            raise ValueError(f"out: expected a C-contiguous array of shape {shape} for {source_name!r}, "
                             f"got shape {out.shape}")
        if source_name == "srp":
            values = self._srp(n)
            if out is None:
                return values
            np.copyto(out, values)
            return out
        return self._white(source_name, shape, out)

    def _white(self, name: str, shape: tuple[int, ...], out: np.ndarray | None = None) -> np.ndarray:
        if not self._enabled[name]:
            if out is None:
                return np.zeros(shape)
            out.fill(0.0)
            return out
        # drawn in place (the same numbers, in the same order, as a new array of this shape)
        draws = self._rngs[name].standard_normal(shape) if out is None else self._rngs[name].standard_normal(out=out)
        # in place, the same products as std * draws (no second array), in rows of _SCALE_STEPS steps
        std_rows = self._std_rows[name]
        flat = draws.reshape(-1)
        whole = flat.size - flat.size % std_rows.size
        rows = flat[:whole].reshape(-1, std_rows.size)
        rows *= std_rows
        flat[whole:] *= std_rows[:flat.size - whole]
        return draws

    def _srp(self, n: int) -> np.ndarray:
        if not self._enabled["srp"]:
            return np.zeros((n, 3))
        params = self.srp_parameters
        innovations = params.innovation_std * self._rngs["srp"].standard_normal((n, 3))
        # x_{k+1} = phi x_k + innovation_k by a C loop; the same arithmetic for any n
        following, _ = lfilter([1.0], [1.0, -params.decay], innovations, axis=0,
                               zi=(params.decay * self._srp_state)[None, :])
        values = np.concatenate((self._srp_state[None, :], following[:-1]), axis=0)
        self._srp_state = following[-1].copy()
        return values

    def draw(self, n: int) -> NoiseDraws:
        """Noise of the next n steps (advances every enabled stream by exactly n steps)."""
        return NoiseDraws(
            thruster_torque_n_m=self._white("thruster_torque", (n, 3)),
            thruster_force_n=self._white("thruster_force", (n, 3)),
            srp_m_s2=self._srp(n),
            lfs_translational_m_s2=self._white("lfs_translational", (n, 2, 3)),
            lfs_rotational_rad_s2=self._white("lfs_rotational", (n, 2, 3)),
            tm_environment_m_s2=self._white("tm_environment", (n, 2, 3)),
            grs_voltage_v=self._white("grs_voltage", (n, 2, 6)),
            star_tracker_rad=self._white("star_tracker", (n, 3)),
        )


def voltage_channel_std_v(linear_equivalent_asd_m_s2_rthz: float, linear_scale_factors: ArrayLike,
                          sample_rate_hz: float) -> np.ndarray:
    """Per-sample standard deviation of each electrode channel's voltage noise.

    Each channel gets the ASD ``S / (sqrt(2) G_P,lin)`` of its axis, so that a sum pair
    ``G_P,lin (v1 + v2)`` shows the linear-equivalent ASD S.

    Parameters
    ----------
    linear_equivalent_asd_m_s2_rthz : float
        S [m s^-2 Hz^-1/2].
    linear_scale_factors : array_like
        (3,) (G_Px, G_Py, G_Pz) [m s^-2 V^-1].
    sample_rate_hz : float
        fs [Hz].

    Returns
    -------
    numpy.ndarray
        (6,) for vx1, vx2, vy1, vy2, vz1, vz2 [V].
    """
    per_axis_asd_v = linear_equivalent_asd_m_s2_rthz / (math.sqrt(2.0) * np.asarray(linear_scale_factors))
    return white_noise_std(np.repeat(per_axis_asd_v, 2), sample_rate_hz)


def linear_readout_noise_std_m_s2(config: SimConfig) -> np.ndarray:
    """Per-sample standard deviation of the noise on each GRS linear readout, every enabled source.

    What the range of the readout has to accommodate on top of the maneuver (the paper: "the linear
    acceleration of the calibration experiment combined with the background noise must fall within
    the measurable range of the GRS"), per sample of the fs readout, by source:

    - thruster force noise ``F / M`` and SRP on ``a_SC`` (CRF, rotated by ``C_i``);
    - thruster torque noise through the mean angular acceleration of the step, ``J^-1 tau``, and the
      lever arm: ``C_i (J^-1 tau) x d_i`` (its slow drift of the rate, ``omega x (omega x d)``, is
      below 1e-6 of the range over days and left out);
    - LFS translational, TM environment (TMRF, per axis) and the electrode voltage noise of the sum
      pair (linear equivalent).

    White sources have ``S sqrt(fs / 2)`` per sample, SRP its stationary standard deviation.

    Parameters
    ----------
    config : SimConfig
        Layout (noise budget and switches, inertia, mass, d_i, C_i, sample rate).

    Returns
    -------
    numpy.ndarray
        (sensors, 3) per GRS and TMRF axis [m s^-2].
    """
    from taiji2_model.frames import crf_to_tmrf

    noise = config.noise
    fs = config.sample_rate_hz
    a_sc_cov = np.zeros((3, 3))
    if noise.thruster_force.enabled:
        a_sc_cov += np.diag((white_noise_std(noise.thruster_force.asd, fs) / config.spacecraft.mass_kg) ** 2
                            * np.ones(3))
    if noise.srp.enabled:
        a_sc_cov += np.eye(3) * srp_ou_parameters(noise.srp, fs).stationary_std ** 2
    torque_cov = np.zeros((3, 3))
    if noise.thruster_torque.enabled:
        torque_cov = np.diag(white_noise_std(noise.thruster_torque.asd, fs) ** 2 * np.ones(3))
    inertia_inv = np.linalg.inv(np.asarray(config.spacecraft.inertia_kg_m2, dtype=np.float64))
    omega_dot_cov = inertia_inv @ torque_cov @ inertia_inv.T
    out = np.empty((len(config.grs.sensors), 3))
    for index, sensor in enumerate(config.grs.sensors):
        d = np.asarray(sensor.com_offset_m, dtype=np.float64)
        # omega_dot x d = -[d]x omega_dot
        skew = np.array([[0.0, -d[2], d[1]], [d[2], 0.0, -d[0]], [-d[1], d[0], 0.0]])
        crf_cov = a_sc_cov + skew @ omega_dot_cov @ skew.T
        c = crf_to_tmrf(sensor.grs_id, config.grs.alpha_rad)
        variance = np.diag(c @ crf_cov @ c.T).copy()
        for name in ("lfs_translational", "tm_environment"):
            source = getattr(noise, name)
            if source.enabled:
                variance += white_noise_std(source.asd, fs) ** 2 * np.ones(3)
        if noise.grs_voltage.enabled:
            variance += float(white_noise_std(noise.grs_voltage.linear_equivalent_asd_m_s2_rthz, fs)) ** 2
        out[index] = np.sqrt(variance)
    return out
