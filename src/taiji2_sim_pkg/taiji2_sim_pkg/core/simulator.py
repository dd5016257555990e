"""The spacecraft simulator: streaming (:meth:`Simulator.step`) and batch (:func:`simulate_batch`).

One step advances from t_k to t_{k+1} = t_k + 1/fs with the commanded torque held constant over
(t_k, t_{k+1}] and returns the sample stamped t_{k+1}:

- star tracker: instantaneous attitude at t_{k+1} with white error;
- GRS (integrating readout): the mean over the step, angular ``C_i (omega_{k+1} - omega_k)/dt``
  and linear ``C_i (a_SC,k + omega_dot x d_i + w_m x (w_m x d_i))``, plus readout noise, converted
  to the six electrode voltages through the true scale factors, plus voltage noise; the linear
  readout ``G_P,lin (v1 + v2)`` then saturates at +-``grs.range_m_s2`` (switch
  ``grs.readout_saturation``, default on; :func:`taiji2_model.grs.saturate_linear_readout`). The
  truth field ``grs_linear_meas`` keeps the unclipped acceleration, what the range check counts.

Timing conventions (``config.timing`` and the timing effects; :mod:`.timing`) are implemented on
the way in and out: the command drives the thrusters through the exact fractional delay and
first-order lag (the thruster noise is not filtered: it is the thrusters' own), and a GRS stamp
offset becomes, equivalently, an extra actuation delay with the star tracker read that much
earlier (a star-tracker stamp offset, applied after every effect).

A block of n steps is computed by the same code whether n = 1 (streaming) or n = whole run (batch);
only the attitude solve differs in the order of its floating-point operations (see
:mod:`.dynamics`), so streaming and batch agree to rounding and their noise draws bitwise.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from taiji2_model.config import SimConfig, TimingConfig
from taiji2_model.effects import Effect
from taiji2_model.frames import crf_to_tmrf
from taiji2_model.grs import saturate_linear_readout
from taiji2_model.maneuver import SquareWaveManeuver
from taiji2_model.noise import NoiseStreams
from taiji2_model.timing import actuation_weights, apply_actuation
from taiji2_sim_pkg.core.attitude_scan import AttitudeScan
from taiji2_sim_pkg.core.dynamics import propagate_attitude
from taiji2_sim_pkg.core.readout import GRS_FIELDS, GrsConstants, grs_readouts_into
from taiji2_sim_pkg.core.star_tracker import star_tracker_covariance_rad2, star_tracker_measurement

#: Steps per chunk of the readout computation (temporaries of a few 100 kB, in cache).
_READOUT_CHUNK_STEPS = 4096

__all__ = [
    "SimOutput",
    "SimSample",
    "SimTruth",
    "Simulator",
    "maneuver_torque_commands",
    "simulate_batch",
]


@dataclass(frozen=True)
class SimTruth:
    """Ground truth of one sample, or of n samples with a leading axis n (CRF unless TMRF noted).

    Attributes
    ----------
    quat_xyzw : numpy.ndarray
        (4,) attitude at the sample time t_{k+1}.
    omega_rad_s : numpy.ndarray
        (3,) body rate at t_{k+1} [rad/s].
    omega_dot_rad_s2 : numpy.ndarray
        (3,) mean angular acceleration over the step [rad s^-2].
    torque_command_n_m : numpy.ndarray
        (3,) commanded torque held over the step [N m].
    torque_applied_n_m : numpy.ndarray
        (3,) applied torque (command + thruster torque noise + effects) [N m].
    a_sc_m_s2 : numpy.ndarray
        (3,) spacecraft non-gravitational acceleration over the step [m s^-2].
    grs_angular_true : numpy.ndarray
        (2, 3) per GRS, TMRF (phi, theta, psi), noise-free ``C_i omega_dot`` [rad s^-2].
    grs_linear_true : numpy.ndarray
        (2, 3) per GRS, TMRF, noise-free ``C_i (a_SC + A~ d_i)`` [m s^-2].
    grs_linear_maneuver : numpy.ndarray
        (2, 3) per GRS, TMRF, rotation-induced part ``C_i A~ d_i`` only [m s^-2].
    grs_angular_meas : numpy.ndarray
        (2, 3) angular readout with readout noise (and effects), before voltage conversion.
    grs_linear_meas : numpy.ndarray
        (2, 3) linear readout with readout noise (and effects), before voltage conversion.
    grs_angular_scale_factors : numpy.ndarray
        (2, 3) true (G_Pphi, G_Ptheta, G_Ppsi) used in the conversion [rad s^-2 V^-1].
    grs_linear_scale_factors : numpy.ndarray
        (2, 3) true (G_Px, G_Py, G_Pz) [m s^-2 V^-1].
    com_offset_m : numpy.ndarray
        (2, 3) true d_i in CRF [m].
    """

    quat_xyzw: np.ndarray
    omega_rad_s: np.ndarray
    omega_dot_rad_s2: np.ndarray
    torque_command_n_m: np.ndarray
    torque_applied_n_m: np.ndarray
    a_sc_m_s2: np.ndarray
    grs_angular_true: np.ndarray
    grs_linear_true: np.ndarray
    grs_linear_maneuver: np.ndarray
    grs_angular_meas: np.ndarray
    grs_linear_meas: np.ndarray
    grs_angular_scale_factors: np.ndarray
    grs_linear_scale_factors: np.ndarray
    com_offset_m: np.ndarray

    def select(self, index: int | slice) -> SimTruth:
        """Index or slice every field along the leading (time) axis."""
        return SimTruth(**{f.name: getattr(self, f.name)[index] for f in fields(self)})


@dataclass(frozen=True)
class SimSample:
    """One 10 Hz sample (what one :meth:`Simulator.step` returns).

    Attributes
    ----------
    t_s : float
        Sample time t_{k+1} [s].
    st_quat_xyzw : numpy.ndarray
        (4,) star-tracker attitude (orientation of the CRF in the inertial frame).
    st_cov_rad2 : numpy.ndarray
        (9,) row-major covariance of the star-tracker error about CRF X, Y, Z [rad^2]; always
        ``diag(sigma^2)`` of the configured sigma, also when the noise is switched off.
    voltages_v : numpy.ndarray
        (2, 6) per GRS, vx1, vx2, vy1, vy2, vz1, vz2 [V].
    truth : SimTruth
        Ground truth.
    """

    t_s: float
    st_quat_xyzw: np.ndarray
    st_cov_rad2: np.ndarray
    voltages_v: np.ndarray
    truth: SimTruth


@dataclass(frozen=True)
class SimOutput:
    """n consecutive samples: the fields of :class:`SimSample` with a leading axis n.

    Fields that are the same at every sample are read-only broadcast views of one value rather
    than copies: ``st_cov_rad2`` always, and the truth's scale factors and c.m. offsets when no
    effect changes them (``np.array(field)`` gives a writable copy).
    """

    t_s: np.ndarray
    st_quat_xyzw: np.ndarray
    st_cov_rad2: np.ndarray
    voltages_v: np.ndarray
    truth: SimTruth

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    def __getitem__(self, index: int) -> SimSample:
        """Sample ``index`` as a :class:`SimSample`."""
        return SimSample(float(self.t_s[index]), self.st_quat_xyzw[index], self.st_cov_rad2[index],
                         self.voltages_v[index], self.truth.select(index))

    def slice(self, start: int | None = None, stop: int | None = None) -> SimOutput:
        """Samples ``start:stop`` as a :class:`SimOutput` (views)."""
        window = slice(start, stop)
        return SimOutput(self.t_s[window], self.st_quat_xyzw[window], self.st_cov_rad2[window],
                         self.voltages_v[window], self.truth.select(window))

    @staticmethod
    def concatenate(parts: Sequence[SimOutput]) -> SimOutput:
        """Join consecutive outputs along time."""
        def join(name: str, owner: str) -> np.ndarray:
            return np.concatenate([getattr(getattr(p, owner) if owner else p, name) for p in parts])

        truth = SimTruth(**{f.name: join(f.name, "truth") for f in fields(SimTruth)})
        return SimOutput(join("t_s", ""), join("st_quat_xyzw", ""), join("st_cov_rad2", ""),
                         join("voltages_v", ""), truth)


def _as_commands(name: str, value: ArrayLike | None, count: int | None) -> np.ndarray:
    array = np.asarray(value, dtype=np.float64)
    if array.ndim != 2 or array.shape[1] != 3 or (count is not None and array.shape[0] != count):
        expected = f"({count}, 3)" if count is not None else "(n, 3)"
        raise ValueError(f"{name}: wrong shape {array.shape}, expected {expected}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name}: must be finite")
    return array


class Simulator:
    """Streaming spacecraft simulator.

    Parameters
    ----------
    config : SimConfig
        Configuration (see :func:`.config.load_config`).
    seed : int, optional
        Run seed (non-negative); ``None`` draws one from the OS, available as :attr:`seed` so the
        run stays reproducible.
    t0_s : float
        Time of the initial state [s].
    effects : sequence of Effect
        Injected effects, applied in order (see :mod:`.effects`).
    """

    def __init__(self, config: SimConfig, seed: int | None = None, t0_s: float = 0.0,
                 effects: Sequence[Effect] = ()) -> None:
        if not isinstance(config, SimConfig):
            raise TypeError(f"config: expected SimConfig, got {type(config).__name__}")
        if seed is None:
            seed = int(np.random.SeedSequence().entropy)  # type: ignore[arg-type]
        self._config = config
        self._noise = NoiseStreams(config, seed)
        self._seed = int(seed)
        self._t0_s = float(t0_s)
        self._dt_s = config.dt_s
        self._step_index = 0
        # the attitude's running product, associated by step index: any chunking gives the same bits
        self._attitude = AttitudeScan(np.array(config.spacecraft.initial_attitude_xyzw, dtype=np.float64))
        self._omega = np.array(config.spacecraft.initial_rate_rad_s, dtype=np.float64)
        self._inertia_inv = np.linalg.inv(config.spacecraft.inertia_kg_m2)
        sensors = config.grs.sensors
        self._grs_constants = GrsConstants(
            grs_ids=tuple(s.grs_id for s in sensors),
            crf_to_tmrf=np.stack([crf_to_tmrf(s.grs_id, config.grs.alpha_rad) for s in sensors]),
            com_offset_m=np.stack([np.asarray(s.com_offset_m, dtype=np.float64) for s in sensors]),
            angular_scale_factors=np.stack([np.asarray(s.angular_scale_factors, dtype=np.float64) for s in sensors]),
            linear_scale_factors=np.stack([np.asarray(s.linear_scale_factors, dtype=np.float64) for s in sensors]),
        )
        self._crf_to_tmrf_pattern = self._grs_constants.crf_to_tmrf_pattern
        self._st_cov_rad2 = star_tracker_covariance_rad2(config.noise.star_tracker.sigma_rad)
        self._effects = tuple(effects)
        timing = config.timing
        for effect in self._effects:
            timing = effect.timing(timing)
        self._timing = timing
        delay_s, st_offset_s, time_constant_s = timing.reduced
        self._actuation: tuple[int, np.ndarray] | None = None
        self._lookahead_steps = 0
        self._command_history = np.zeros((0, 3))
        if delay_s != 0.0 or time_constant_s != 0.0:
            m_first, weights = actuation_weights(delay_s, time_constant_s, self._dt_s)
            self._actuation = (m_first, weights)
            self._lookahead_steps = max(-m_first, 0)
            self._command_history = np.zeros((max(m_first + weights.size - 1, 0), 3))
        hooks = list(self._effects)
        if st_offset_s != 0.0:
            from taiji2_model.effect_catalog import TimeOffset  # the catalog builds on this module's Effect users

            hooks.append(TimeOffset(st_offset_s))
        self._hooks = tuple(hooks)
        for effect in self._hooks:
            effect.bind(config, self._seed)

    # state and provenance ---------------------------------------------------------------------
    @property
    def config(self) -> SimConfig:
        """The configuration."""
        return self._config

    @property
    def seed(self) -> int:
        """The run seed (record it: it reproduces the run)."""
        return self._seed

    @property
    def t0_s(self) -> float:
        """Time of the initial state [s]."""
        return self._t0_s

    @property
    def step_index(self) -> int:
        """Number of steps taken."""
        return self._step_index

    @property
    def time_s(self) -> float:
        """Current time t_k [s] (stamp of the last sample, t0 before the first step)."""
        return self._t0_s + self._step_index * self._dt_s

    @property
    def quat_xyzw(self) -> np.ndarray:
        """Current true attitude (4,) (copy)."""
        return self._attitude.attitude_xyzw

    @property
    def omega_rad_s(self) -> np.ndarray:
        """Current true body rate (3,) [rad/s] (copy)."""
        return self._omega.copy()

    @property
    def effects(self) -> tuple[Effect, ...]:
        """Injected effects."""
        return self._effects

    @property
    def timing(self) -> TimingConfig:
        """Timing conventions in force (configuration plus timing effects)."""
        return self._timing

    @property
    def lookahead_steps(self) -> int:
        """Later commands each step needs (> 0 for a negative total actuation delay: batch only)."""
        return self._lookahead_steps

    def provenance(self) -> dict[str, Any]:
        """Everything needed to reproduce the run: seed, t0, configuration and effects."""
        return {"seed": self._seed, "t0_s": self._t0_s, "config": self._config.to_dict(),
                "effects": [effect.to_dict() for effect in self._effects]}

    # stepping -------------------------------------------------------------------------------
    def step(self, torque_cmd_n_m: ArrayLike, force_cmd_n: ArrayLike | None = None) -> SimSample:
        """Advance one step holding the command (zero-order hold).

        Parameters
        ----------
        torque_cmd_n_m : array_like
            (3,) commanded torque about the CRF axes over (t_k, t_{k+1}] [N m].
        force_cmd_n : array_like, optional
            (3,) commanded force in CRF [N] (zero for the paper's maneuvers).

        Returns
        -------
        SimSample
            The sample stamped t_{k+1}.
        """
        torque = np.asarray(torque_cmd_n_m, dtype=np.float64).reshape(1, -1)
        force = None if force_cmd_n is None else np.asarray(force_cmd_n, dtype=np.float64).reshape(1, -1)
        return self.advance(torque, force)[0]

    def advance(self, torque_cmd_n_m: ArrayLike, force_cmd_n: ArrayLike | None = None) -> SimOutput:
        """Advance n steps at once (batch), continuing from the current state.

        Parameters
        ----------
        torque_cmd_n_m : array_like
            (n, 3) commanded torque of each step [N m].
        force_cmd_n : array_like, optional
            (n, 3) commanded force of each step, CRF [N].

        Returns
        -------
        SimOutput
            n samples stamped t_{k+1} .. t_{k+n}; identical (to rounding) to n calls of :meth:`step`.
        """
        command = _as_commands("torque_cmd_n_m", torque_cmd_n_m, None)
        count = command.shape[0]
        config = self._config
        step_numbers = self._step_index + np.arange(count + 1, dtype=np.float64)
        times = self._t0_s + step_numbers * self._dt_s
        t_start, t_end = times[:-1], times[1:]
        noise = self._noise  # one generator per source: drawing them one by one is bitwise draw(count)
        # applied torque and spacecraft acceleration in one allocation; each noise is drawn into the
        # array it is added to (noise + x is the sum x + noise)
        spacecraft = np.empty((2, count, 3))
        torque = noise.draw_source("thruster_torque", count, out=spacecraft[0])
        torque += self._actuate(command)
        inertia = config.spacecraft.inertia_kg_m2
        for effect in self._hooks:
            torque = effect.applied_torque_n_m(t_start, torque)
            inertia = effect.inertia_kg_m2(t_start, inertia)
        # the configured J keeps its precomputed inverse; an effect's J is inverted per block
        inertia_inv = self._inertia_inv if inertia is config.spacecraft.inertia_kg_m2 else None
        attitude = propagate_attitude(self._attitude, self._omega, torque, inertia, self._dt_s, inertia_inv)

        a_sc = noise.draw_source("thruster_force", count, out=spacecraft[1])
        if force_cmd_n is not None:
            a_sc += _as_commands("force_cmd_n", force_cmd_n, count)
        a_sc /= config.spacecraft.mass_kg
        a_sc += noise.draw_source("srp", count)
        for effect in self._hooks:
            a_sc = effect.spacecraft_acceleration_m_s2(t_start, a_sc)

        # Readouts, step by step independent: in chunks of steps, so that their temporaries stay
        # small (in cache, reused from the heap rather than fresh pages), with the readout noise
        # drawn chunk by chunk into the output arrays; effects see the whole block at once (some
        # filter over time) and one GRS at a time (their hooks are per GRS).
        sensor_count = len(config.grs.sensors)
        # without effects, the scale factors and offsets are the configured ones at every step:
        # read-only broadcast views instead of copies
        constant = {} if self._hooks else {
            "com_offset": self._grs_constants.com_offset_m,
            "angular_sf": self._grs_constants.angular_scale_factors,
            "linear_sf": self._grs_constants.linear_scale_factors,
        }
        grs = {key: np.broadcast_to(constant[key], (count, sensor_count, width)) if key in constant
               else np.empty((count, sensor_count, width)) for key, width in GRS_FIELDS}
        st_quat = np.empty((count, 4))
        chunk = max(count, 1) if self._hooks else _READOUT_CHUNK_STEPS
        groups = [slice(i, i + 1) for i in range(sensor_count)] if self._hooks else [slice(0, sensor_count)]
        tm_noise = np.empty((min(chunk, count), sensor_count, 3))
        star_tracker_noise = np.empty((min(chunk, count), 3))
        for start in range(0, count, chunk):
            window = slice(start, min(start + chunk, count))
            size = window.stop - start
            block = {key: array[window] for key, array in grs.items() if key not in constant}
            noise.draw_source("lfs_rotational", size, out=block["angular_meas"])
            noise.draw_source("lfs_translational", size, out=block["linear_meas"])
            noise.draw_source("grs_voltage", size, out=block["voltages"])
            noise.draw_source("tm_environment", size, out=tm_noise[:size])
            for group in groups:
                grs_readouts_into(block, tm_noise[:size, group], group, self._grs_constants, t_end[window],
                                  attitude.omega_dot_rad_s2[window], attitude.omega_mid_rad_s[window],
                                  a_sc[window], self._hooks, self._crf_to_tmrf_pattern)
            error = noise.draw_source("star_tracker", size, out=star_tracker_noise[:size])
            quat = star_tracker_measurement(attitude.quat_xyzw[window], error)
            for effect in self._hooks:
                quat = effect.star_tracker_quat_xyzw(t_end[window], quat)
            st_quat[window] = quat
        if config.grs.readout_saturation:  # the readout rails: after every effect, as the electronics
            saturate_linear_readout(grs["voltages"], grs["linear_sf"], config.grs.range_m_s2)

        self._omega = attitude.omega_rad_s[-1].copy()
        self._step_index += count
        truth = SimTruth(
            quat_xyzw=attitude.quat_xyzw,
            omega_rad_s=attitude.omega_rad_s,
            omega_dot_rad_s2=attitude.omega_dot_rad_s2,
            torque_command_n_m=command,
            torque_applied_n_m=torque,
            a_sc_m_s2=a_sc,
            grs_angular_true=grs["angular_true"],
            grs_linear_true=grs["linear_true"],
            grs_linear_maneuver=grs["linear_maneuver"],
            grs_angular_meas=grs["angular_meas"],
            grs_linear_meas=grs["linear_meas"],
            grs_angular_scale_factors=grs["angular_sf"],
            grs_linear_scale_factors=grs["linear_sf"],
            com_offset_m=grs["com_offset"],
        )
        # the reported covariance is the same at every sample: a read-only broadcast view
        return SimOutput(t_end, st_quat, np.broadcast_to(self._st_cov_rad2, (count, 9)), grs["voltages"], truth)

    def _actuate(self, command: np.ndarray) -> np.ndarray:
        """Mean thrust torque over each step from the commands (exact delay and lag; :mod:`.timing`).

        Streaming keeps the commands the filter still needs; with a negative total delay (lookahead)
        the commands after the block are taken equal to its last one, so only a single batch over
        the whole run is exact.
        """
        if self._actuation is None:
            return command
        m_first, weights = self._actuation
        history = self._command_history
        count = command.shape[0]
        lookahead = np.broadcast_to(command[-1], (self._lookahead_steps, 3))
        padded = np.concatenate((history, command, lookahead))
        head = history.shape[0]
        out = apply_actuation(padded, head, count, m_first, weights)
        if head:
            self._command_history = np.concatenate((history, command))[-head:]
        return out


def simulate_batch(config: SimConfig, seed: int | None, torque_cmd_n_m: ArrayLike, t0_s: float = 0.0,
                   force_cmd_n: ArrayLike | None = None, effects: Sequence[Effect] = ()) -> SimOutput:
    """Simulate a whole experiment at once.

    Parameters
    ----------
    config : SimConfig
        Configuration.
    seed : int or None
        Run seed (see :class:`Simulator`).
    torque_cmd_n_m : array_like
        (n, 3) commanded torque held over each step [N m] (e.g. :func:`maneuver_torque_commands`).
    t0_s : float
        Initial time [s].
    force_cmd_n : array_like, optional
        (n, 3) commanded force [N].
    effects : sequence of Effect
        Injected effects.

    Returns
    -------
    SimOutput
        n samples, identical to n calls of :meth:`Simulator.step` with the same seed.
    """
    return Simulator(config, seed=seed, t0_s=t0_s, effects=effects).advance(torque_cmd_n_m, force_cmd_n)


def maneuver_torque_commands(config: SimConfig, n_steps: int | None = None, t0_s: float = 0.0,
                             maneuver: Any = None) -> np.ndarray:
    """Torque commands of the configured maneuver, one per step, sampled at the step starts.

    Parameters
    ----------
    config : SimConfig
        Configuration (maneuver and sample rate).
    n_steps : int, optional
        Number of steps; default: up to the end of the maneuver, ``round((end - t0) fs)``.
    t0_s : float
        Initial time [s].
    maneuver : object, optional
        Any maneuver family (:mod:`.maneuver_families`, e.g. from a maneuver file) instead of the
        configured square wave; the sampling is the same as the maneuver_commander's.

    Returns
    -------
    numpy.ndarray
        (n_steps, 3) command held over (t_k, t_{k+1}], t_k = t0 + k / fs [N m].
    """
    if maneuver is None:
        maneuver = SquareWaveManeuver.from_config(config.maneuver)
    if n_steps is None:
        n_steps = max(0, round((maneuver.end_s - t0_s) * config.sample_rate_hz))
    return maneuver.torque_series(t0_s + np.arange(n_steps, dtype=np.float64) * config.dt_s)
