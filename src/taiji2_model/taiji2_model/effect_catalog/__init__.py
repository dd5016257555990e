"""Catalog of unmodelled effects: named switches with physical magnitudes in SI units.

Each entry is an :class:`~.effects.Effect` subclass, usable both to make "real" data (pass it to
:class:`~.simulator.Simulator` or :func:`~.simulator.simulate_batch`) and, in the sim-to-real gap
diagnosis, as a candidate extension of the nominal model (the diagnosis derives the signature of
each entry from the same definitions; ``docs/diagnosis.md``).

Every effect has an ``enabled`` switch; disabled, or with all magnitudes zero, it returns its
inputs unchanged, so the data are bit-identical to a run without it. Frames and signs follow
``docs/physics_model.md``: CRF vectors, TMRF readouts ``C_i v``; angular readouts
``(phi, theta, psi)``, linear ``(x, y, z)``; the electrode pair ``x`` carries ``psi`` (difference)
and ``x`` (sum), ``y`` carries ``phi`` and ``y``, ``z`` carries ``theta`` and ``z``.

=============================  ==================================================================
name                           model (magnitude parameters, SI)
=============================  ==================================================================
scale_factor_drift             G(t) = G (1 + rate (t - t_ref)) of one electrode pair of one GRS,
                               angular and linear together (``rate_per_s`` [1/s])
cross_coupling                 TMRF misalignment ``a -> a - eps x a`` (``misalignment_rad``) and
                               electrode gain imbalance ``v1 (1 + eta), v2 (1 - eta)``, which
                               couples angular and linear (``imbalance`` [1])
time_offset                    star tracker stamped ``offset_s`` late: it reads q(t - offset) [s]
actuation_delay                the applied torque lags the command by ``delay_s`` [s] (any sign)
thruster_response              first-order lag of the applied torque, ``time_constant_s`` [s]
grs_time_offset                GRS stamped ``offset_s`` late against the model's convention [s]
star_tracker_lowfreq_noise     extra star-tracker error, PSD ``S_w f_knee^2 / (f^2 + f_c^2)``
                               (``knee_hz``: where it equals the white level S_w) [Hz]
thruster_torque_gain           applied torque = (1 + g_k) x (command + noise) per axis (``gain``)
com_drift                      d_i(t) = d_i + v (t - t_ref) for GRS 1, 2 or both (``rate_m_s``)
readout_nonlinearity           a_meas = a + k a^2 on one readout of one GRS (``k`` [1/(unit)])
inertia_error                  J_true = J + diag(eps J_kk) + products of inertia
                               (``relative``, ``products_kg_m2``)
gravity_gradient               3 n^2 r x J r for a circular orbit of period ``orbit_period_s``
                               (orbit normal, phase; ``scale`` multiplies the torque)
tm_stiffness                   TM-to-spacecraft stiffness k acting on the suspension's tracking
                               error x_rel = -H(s) a_req: the GRS reads a_req - k H(s) a_req
                               (``stiffness_s2`` [s^-2], suspension frequency, damping)
thruster_force_leakage         net force F = Lambda tau from the torque maneuver: a_SC += F / M
                               (``leakage_per_m`` (3, 3) [N / (N m)])
impulse                        a delta impulse at ``time_s``: angular momentum
                               ``angular_momentum_n_m_s`` [N m s] and linear impulse
                               ``linear_impulse_n_s`` [N s] (a micrometeoroid impact)
=============================  ==================================================================

Registry: :data:`EFFECTS` (name -> class), :func:`make_effect` and :func:`effects_from_config`.
"""

from __future__ import annotations

from taiji2_model.effect_catalog.base import ANGULAR_READOUTS, ELECTRODE_PAIRS, LINEAR_READOUTS, EffectParameterError
from taiji2_model.effect_catalog.dynamics import (
    ComDrift,
    GravityGradient,
    InertiaError,
    ThrusterForceLeakage,
    ThrusterTorqueGain,
)
from taiji2_model.effect_catalog.impulse import Impulse
from taiji2_model.effect_catalog.readout import CrossCoupling, ReadoutNonlinearity, ScaleFactorDrift
from taiji2_model.effect_catalog.registry import EFFECTS, effects_from_config, make_effect
from taiji2_model.effect_catalog.star_tracker import StarTrackerLowFreqNoise
from taiji2_model.effect_catalog.test_mass import TmStiffness, suspension_filter
from taiji2_model.effect_catalog.timing import ActuationDelay, GrsTimeOffset, ThrusterResponse, TimeOffset

__all__ = [
    "ANGULAR_READOUTS",
    "EFFECTS",
    "ELECTRODE_PAIRS",
    "LINEAR_READOUTS",
    "ActuationDelay",
    "ComDrift",
    "CrossCoupling",
    "EffectParameterError",
    "GravityGradient",
    "GrsTimeOffset",
    "Impulse",
    "InertiaError",
    "ReadoutNonlinearity",
    "ScaleFactorDrift",
    "StarTrackerLowFreqNoise",
    "ThrusterForceLeakage",
    "ThrusterResponse",
    "ThrusterTorqueGain",
    "TimeOffset",
    "TmStiffness",
    "effects_from_config",
    "make_effect",
    "suspension_filter",
]
