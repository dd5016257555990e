"""Reference fidelity: an independently discretised data source (what real data look like to the model).

The standard simulator (:mod:`.simulator`) advances at the 10 Hz readout rate with the command held
over each step and an integrating (boxcar) GRS readout, i.e. the very conventions of the nominal
model. The reference simulator shares only the physics and the noise budget (paper values):

- internal rate ``substeps`` x fs (default 200 Hz) with the implicit midpoint rule (second order;
  at 5 ms steps its error is below 1e-9 of the maneuver rate);
- thrusters: the zero-order-hold command through the latency and first-order lag of the timing
  conventions, averaged exactly over each internal step (:mod:`.timing`); thruster torque and force
  noise white at the internal rate (the same ASD), SRP an Ornstein-Uhlenbeck process at that rate;
- GRS: the internal-rate accelerations through a linear-phase anti-alias FIR (Kaiser-windowed
  sinc, cut-off 0.4 fs, 81 taps at 200 Hz) and decimated to fs; the sample whose filter is centred
  on ``c`` is stamped ``c + dt/2 + grs_stamp`` (the low-frequency timing of the ``end`` convention,
  shifted by the configured stamp offset); readout and voltage noise then at fs; the linear
  readout saturates at the range (``grs.readout_saturation``), as in the standard simulator;
- star tracker: the attitude averaged over an exposure (default one sample interval) centred on
  ``stamp - star_tracker_stamp_offset_s``, plus its white error.

Catalog effects apply at the rate where their physics sits: torque, inertia, spacecraft
acceleration and c.m. offset hooks at the internal rate; GRS readout, scale-factor and voltage
hooks, and star-tracker noise hooks, on the 10 Hz samples. Timing effects (``actuation_delay``,
``thruster_response``, ``grs_time_offset``, ``time_offset``) enter the timing conventions.
Batch only: the whole command series is known.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike
from scipy.signal import lfilter

from taiji2_model.config import SimConfig
from taiji2_model.effects import Effect
from taiji2_model.frames import (
    apply_matrix,
    crf_to_tmrf,
    quat_conjugate,
    quat_from_rotvec,
    quat_multiply,
    rotvec_from_quat,
)
from taiji2_model.grs import coupling_acceleration_m_s2, saturate_linear_readout, voltages_from_accelerations
from taiji2_model.noise import NoiseStreams, noise_rng, srp_ou_parameters, white_noise_std
from taiji2_model.timing import actuated_commands
from taiji2_sim_pkg.core.dynamics import AttitudeSteps, propagate_attitude
from taiji2_sim_pkg.core.simulator import SimOutput, SimTruth
from taiji2_sim_pkg.core.star_tracker import star_tracker_covariance_rad2, star_tracker_measurement

__all__ = ["ReferenceSettings", "simulate_reference"]


@dataclass(frozen=True)
class ReferenceSettings:
    """Discretisation of the reference simulator.

    Attributes
    ----------
    substeps : int
        Internal steps per readout sample (internal rate = substeps x fs).
    fir_half_width_samples : float
        Half length of the GRS anti-alias FIR, in readout samples.
    fir_cutoff_fraction : float
        FIR cut-off as a fraction of fs.
    fir_kaiser_beta : float
        Kaiser window parameter of the FIR.
    st_exposure_s : float or None
        Star-tracker exposure [s] (None: one readout interval).
    st_exposure_points : int
        Points of the exposure average.
    """

    substeps: int = 20
    fir_half_width_samples: float = 2.0
    fir_cutoff_fraction: float = 0.4
    fir_kaiser_beta: float = 6.0
    st_exposure_s: float | None = None
    st_exposure_points: int = 9


def _fir(offsets_s: np.ndarray, cutoff_hz: float, half_width_s: float, beta: float) -> np.ndarray:
    """Kaiser-windowed sinc evaluated at time offsets from its centre, normalised to unit DC gain."""
    taps = 2.0 * cutoff_hz * np.sinc(2.0 * cutoff_hz * offsets_s)
    inside = np.abs(offsets_s) < half_width_s
    window = np.zeros_like(offsets_s)
    window[inside] = np.i0(beta * np.sqrt(1.0 - (offsets_s[inside] / half_width_s) ** 2)) / np.i0(beta)
    taps = taps * window
    return taps / np.sum(taps)


def _timing(config: SimConfig, effects: Sequence[Effect]) -> tuple[float, float, float, float]:
    """(GRS stamp offset, star-tracker offset, actuation latency, thruster time constant) [s]."""
    from taiji2_model.effect_catalog import TimeOffset  # the catalog builds on the simulator modules

    timing = config.timing
    st_extra = 0.0
    for effect in effects:
        if isinstance(effect, TimeOffset):
            st_extra += effect.offset_s if effect.active and effect.onset_s <= 0.0 else 0.0
        else:
            timing = effect.timing(timing)
    timing = replace(timing, star_tracker_stamp_offset_s=timing.star_tracker_stamp_offset_s + st_extra)
    return (timing.grs_stamp, timing.star_tracker_stamp_offset_s, timing.actuation_latency_s,
            timing.thruster_time_constant_s)


def simulate_reference(config: SimConfig, seed: int, torque_cmd_n_m: ArrayLike, t0_s: float = 0.0,
                       effects: Sequence[Effect] = (), settings: ReferenceSettings | None = None) -> SimOutput:
    """Simulate an experiment at reference fidelity.

    Parameters
    ----------
    config : SimConfig
        Layout (physics, noise, timing conventions).
    seed : int
        Run seed (its own streams: the noise differs from the standard simulator's).
    torque_cmd_n_m : array_like
        (n, 3) command stamped t0 + k dt, held over (t_k, t_k + dt] [N m]; idle before.
    t0_s : float
        Time of the initial state [s].
    effects : sequence of Effect
        Catalog effects (see the module docstring for where each applies).
    settings : ReferenceSettings, optional
        Discretisation.

    Returns
    -------
    SimOutput
        n samples stamped t0 + (k + 1) dt, the fields of the standard simulator's output.
    """
    settings = settings or ReferenceSettings()
    command = np.asarray(torque_cmd_n_m, dtype=np.float64)
    if command.ndim != 2 or command.shape[1] != 3 or not np.all(np.isfinite(command)):
        raise ValueError(f"torque_cmd_n_m: expected finite (n, 3), got shape {command.shape}")
    if settings.substeps < 2:
        raise ValueError(f"substeps: at least 2, got {settings.substeps}")
    effects = tuple(effects)
    for effect in effects:
        effect.bind(config, seed)
    grs_stamp_s, st_offset_s, latency_s, time_constant_s = _timing(config, effects)
    n = command.shape[0]
    dt = config.dt_s
    sub = settings.substeps
    h = dt / sub
    fir_half_s = settings.fir_half_width_samples * dt
    exposure_s = dt if settings.st_exposure_s is None else settings.st_exposure_s
    # internal grid: idle before t0 and the last command held after the record, wide enough for
    # every filter window and stamp offset
    onset_offsets = [abs(e.offset_s) for e in effects if getattr(e, "name", "") == "time_offset"
                     and getattr(e, "onset_s", 0.0) > 0.0]
    reach = fir_half_s + exposure_s + abs(grs_stamp_s) + abs(st_offset_s) + sum(onset_offsets) + 2.0 * dt
    pad = math.ceil(reach / dt) + 1
    samples = np.concatenate((np.zeros((pad, 3)), command, np.repeat(command[-1:], pad, axis=0)))
    t_start = t0_s - pad * dt
    fine_count = samples.shape[0] * sub
    fine_start = t_start + np.arange(fine_count) * h  # start of each internal step

    # thrust, torque and attitude at the internal rate -------------------------------------------
    fine_command = np.repeat(samples, sub, axis=0)
    torque = actuated_commands(fine_command, latency_s, time_constant_s, h)
    noise = config.noise
    fs_fine = 1.0 / h
    if noise.thruster_torque.enabled:
        torque = torque + white_noise_std(noise.thruster_torque.asd, fs_fine) * noise_rng(
            seed, "reference.thruster_torque").standard_normal((fine_count, 3))
    inertia = config.spacecraft.inertia_kg_m2
    for effect in effects:
        torque = effect.applied_torque_n_m(fine_start, torque)
        inertia = effect.inertia_kg_m2(fine_start, inertia)
    rest = np.array(config.spacecraft.initial_attitude_xyzw, dtype=np.float64)
    omega0 = np.array(config.spacecraft.initial_rate_rad_s, dtype=np.float64)
    attitude = propagate_attitude(rest, omega0, torque, inertia, h)
    force = np.zeros((fine_count, 3))
    if noise.thruster_force.enabled:
        force = white_noise_std(noise.thruster_force.asd, fs_fine) * noise_rng(
            seed, "reference.thruster_force").standard_normal((fine_count, 3))
    a_sc = force / config.spacecraft.mass_kg
    if noise.srp.enabled:
        ou = srp_ou_parameters(noise.srp, fs_fine)
        rng = noise_rng(seed, "reference.srp")
        state = ou.stationary_std * rng.standard_normal(3)
        a_sc = a_sc + lfilter([1.0], [1.0, -ou.decay], ou.innovation_std * rng.standard_normal((fine_count, 3)),
                              axis=0, zi=(ou.decay * state)[None, :])[0]
    for effect in effects:
        a_sc = effect.spacecraft_acceleration_m_s2(fine_start, a_sc)

    # GRS: anti-alias FIR on the internal-rate accelerations, decimated -----------------------------
    stamps = t0_s + (np.arange(n) + 1.0) * dt
    centres = stamps - 0.5 * dt - grs_stamp_s  # time each sample's filter is centred on
    fine_mid = fine_start + 0.5 * h  # each internal step's mean acceleration belongs to its midpoint
    first = np.ceil((centres[0] - fir_half_s - fine_mid[0]) / h).astype(int)
    last = np.floor((centres[0] + fir_half_s - fine_mid[0]) / h).astype(int)
    offsets = np.arange(first, last + 1)
    taps = _fir(centres[0] - fine_mid[offsets], settings.fir_cutoff_fraction / dt, fir_half_s,
                settings.fir_kaiser_beta)

    def decimate(series: np.ndarray) -> np.ndarray:
        out = np.zeros((n, *series.shape[1:]))
        for offset, tap in zip(offsets, taps, strict=True):
            out += tap * series[offset: offset + n * sub: sub]
        return out

    readout_noise = NoiseStreams(config, seed).draw(n)
    sensors = config.grs.sensors
    fields: dict[str, np.ndarray] = {key: np.empty((n, 2, 3)) for key in (
        "angular_true", "linear_true", "linear_maneuver", "angular_meas", "linear_meas", "angular_sf", "linear_sf",
        "com_offset")}
    voltages = np.empty((n, 2, 6))
    for index, sensor in enumerate(sensors):
        c_tmrf = crf_to_tmrf(sensor.grs_id, config.grs.alpha_rad)
        com_offset = sensor.com_offset_m
        for effect in effects:
            com_offset = effect.com_offset_m(fine_mid, sensor.grs_id, com_offset)
        coupling = coupling_acceleration_m_s2(attitude.omega_dot_rad_s2, attitude.omega_mid_rad_s, com_offset)
        angular_true = decimate(apply_matrix(c_tmrf, attitude.omega_dot_rad_s2))
        linear_maneuver = decimate(apply_matrix(c_tmrf, coupling))
        linear_true = linear_maneuver + decimate(apply_matrix(c_tmrf, a_sc))
        angular = angular_true + readout_noise.lfs_rotational_rad_s2[:, index]
        linear = (linear_true + readout_noise.lfs_translational_m_s2[:, index]
                  + readout_noise.tm_environment_m_s2[:, index])
        angular_sf, linear_sf = sensor.angular_scale_factors, sensor.linear_scale_factors
        for effect in effects:
            angular, linear = effect.grs_accelerations(stamps, sensor.grs_id, angular, linear)
            angular_sf, linear_sf = effect.grs_scale_factors(stamps, sensor.grs_id, angular_sf, linear_sf)
        volts = voltages_from_accelerations(angular, linear, angular_sf, linear_sf)
        volts = volts + readout_noise.grs_voltage_v[:, index]
        for effect in effects:
            volts = effect.grs_voltages_v(stamps, sensor.grs_id, volts)
        if config.grs.readout_saturation:  # the readout rails, after every effect (as the standard simulator)
            volts = saturate_linear_readout(np.array(volts, dtype=np.float64), linear_sf, config.grs.range_m_s2)
        voltages[:, index] = volts
        com_at_stamps = np.broadcast_to(com_offset, (fine_count, 3))[pad * sub + sub - 1:: sub][:n]
        for key, value in (("angular_true", angular_true), ("linear_true", linear_true),
                           ("linear_maneuver", linear_maneuver), ("angular_meas", angular), ("linear_meas", linear),
                           ("angular_sf", np.broadcast_to(angular_sf, (n, 3))),
                           ("linear_sf", np.broadcast_to(linear_sf, (n, 3))), ("com_offset", com_at_stamps)):
            fields[key][:, index] = value

    # star tracker: attitude averaged over the exposure ---------------------------------------------
    from taiji2_model.effect_catalog import TimeOffset

    reads = stamps - st_offset_s
    for effect in effects:  # a star-tracker offset from an onset on (before it: the conventions')
        if isinstance(effect, TimeOffset) and effect.active and effect.onset_s > 0.0:
            reads = reads - np.where(stamps >= effect.onset_s, effect.offset_s, 0.0)
    points = (np.arange(settings.st_exposure_points) + 0.5) / settings.st_exposure_points - 0.5
    fine_end = fine_start + h
    reference_quat = _attitude_at(reads, fine_end, attitude, rest)
    conj = quat_conjugate(reference_quat)
    mean_rotvec = np.zeros((n, 3))
    for point in points:
        q = _attitude_at(reads + point * exposure_s, fine_end, attitude, rest)
        mean_rotvec += rotvec_from_quat(quat_multiply(conj, q)) / points.size
    true_quat = quat_multiply(reference_quat, quat_from_rotvec(mean_rotvec))
    st_quat = star_tracker_measurement(true_quat, readout_noise.star_tracker_rad)
    for effect in effects:
        if not isinstance(effect, TimeOffset):
            st_quat = effect.star_tracker_quat_xyzw(stamps, st_quat)

    # truth on the readout grid ----------------------------------------------------------------------
    window = slice(pad * sub, (pad + n) * sub)
    per_sample = (n, sub, 3)
    truth = SimTruth(
        quat_xyzw=_attitude_at(stamps, fine_end, attitude, rest),
        omega_rad_s=attitude.omega_rad_s[pad * sub + sub - 1:: sub][:n],
        omega_dot_rad_s2=attitude.omega_dot_rad_s2[window].reshape(per_sample).mean(axis=1),
        torque_command_n_m=command,
        torque_applied_n_m=torque[window].reshape(per_sample).mean(axis=1),
        a_sc_m_s2=a_sc[window].reshape(per_sample).mean(axis=1),
        grs_angular_true=fields["angular_true"],
        grs_linear_true=fields["linear_true"],
        grs_linear_maneuver=fields["linear_maneuver"],
        grs_angular_meas=fields["angular_meas"],
        grs_linear_meas=fields["linear_meas"],
        grs_angular_scale_factors=fields["angular_sf"],
        grs_linear_scale_factors=fields["linear_sf"],
        com_offset_m=fields["com_offset"],
    )
    cov = np.tile(star_tracker_covariance_rad2(noise.star_tracker.sigma_rad), (n, 1))
    return SimOutput(stamps, st_quat, cov, voltages, truth)


def _attitude_at(times: np.ndarray, fine_end: np.ndarray, attitude: AttitudeSteps, rest: np.ndarray) -> np.ndarray:
    """Attitude at arbitrary times: the internal step's start attitude rotated at its midpoint rate."""
    h = fine_end[1] - fine_end[0]
    index = np.clip(np.ceil((times - fine_end[0]) / h).astype(int), 0, fine_end.shape[0] - 1)  # step ending after t
    start_quat = np.where((index > 0)[:, None], attitude.quat_xyzw[np.maximum(index - 1, 0)], rest)
    elapsed = times - (fine_end[index] - h)
    return quat_multiply(start_quat, quat_from_rotvec(attitude.omega_mid_rad_s[index] * elapsed[:, None]))
