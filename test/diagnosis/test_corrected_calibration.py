"""The corrected calibration (stage 7, diagnosis/stages/corrected.py, extended.corrected_calibration) per
effect family: the readout effects of a GRS (effect_catalog/readout.py: cross-talk, scale-factor drift,
nonlinearity), the dynamics (effect_catalog/dynamics.py: torque gain, inertia error, force leakage, gravity
gradient) and the test mass (effect_catalog/test_mass.py: stiffness). The timing family's corrected
calibration is checked where the diagnosis of a timing effect is run (test_timing_diagnosis.py,
test_diagnose.py); the impulse's in test_impulses.py; benchmarks/bench_corrected_calibration.py has every
variant at 5-50 sigma of bias, both layouts, both fidelities, with and without an onset.

Issue 39: a named cross-talk made the calibration worse (G 12 -> 78 sigma). The named effects were held at
their fitted values and G re-fitted with G's conditional sigma; an electrode imbalance moves G by eta d / r
(six times eta on Type-1), so a value off by its own sigma moved G by many of G's sigmas, and an unnamed part of
the cross-talk, absorbed by the named terms, moved it further. Now the named effects are re-fitted with G and d
(sigmas marginal over them), and the whole cross-talk of a GRS where a gap stays unexplained beside it.

Seeded statistical checks, tolerances in sigmas of each calibration: the corrected G and d within 3 sigma of the
truth, and no further from it than the nominal calibration + 1 sigma (worst component of each). Type-1, unclipped
readout (conftest), standard simulator.
"""

from __future__ import annotations

import numpy as np
import pytest

from taiji2_estimator_pkg.diagnosis import DiagnosisOptions, diagnose, prepare_input
from taiji2_estimator_pkg.diagnosis.extended import corrected_calibration, fixed_from_specs
from taiji2_estimator_pkg.diagnosis.model import NominalModel
from taiji2_estimator_pkg.diagnosis.options import record_settings
from taiji2_estimator_pkg.diagnosis.record import calibrate
from taiji2_estimator_pkg.diagnosis.stages.corrected import CORRECTED_ITERATIONS, untrusted
from taiji2_model.config import load_config
from taiji2_model.effect_catalog import make_effect
from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch

from support import calibration_z

HOUR = 36000


def _data(effects, n, seed):
    config = load_config("type1")
    commands = maneuver_torque_commands(config, n)
    out = simulate_batch(config, seed, commands, effects=[make_effect(**e) for e in effects])
    return config, prepare_input(out.t_s, out.st_quat_xyzw, out.voltages_v, commands, config.sample_rate_hz)


def _worst_z(config, calibration):
    """Worst |error| / sigma of G and of d against the layout's truth."""
    z = calibration_z(calibration, [s.angular_scale_factors for s in config.grs.sensors],
                      [s.com_offset_m for s in config.grs.sensors])
    return float(np.max(np.abs(z[:6]))), float(np.max(np.abs(z[6:])))


def _assert_corrected(config, nominal, corrected, g_min=5.0):
    nominal_g, nominal_d = _worst_z(config, nominal)
    corrected_g, corrected_d = _worst_z(config, corrected)
    assert max(nominal_g, nominal_d) > g_min, (nominal_g, nominal_d)  # the effect biases the nominal G or d
    assert corrected_g < 3.0 and corrected_d < 3.0, (nominal_g, nominal_d, corrected_g, corrected_d)
    assert corrected_g <= nominal_g + 1.0 and corrected_d <= nominal_d + 1.0, (nominal_g, nominal_d, corrected_g,
                                                                               corrected_d)


def test_named_part_of_a_cross_talk_corrects_the_calibration():
    """GRS1 cross-talk (misalignment about three axes, imbalance of three pairs, 1 h, seed 23): the selection
    names the three imbalances, a gap stays unexplained. Before issue 39 the corrected G was 15.9 sigma off (the
    imbalances absorbed the misalignment), the nominal one 10.3; re-fitted with the whole cross-talk of GRS1
    it is 2.3 sigma off (d: 2.8 nominal, 1.4 corrected)."""
    effect = {"name": "cross_coupling", "grs": 1, "misalignment_rad": [4e-4, -5e-4, 6e-4],
              "imbalance": [2e-4, -2e-4, 3e-4]}
    config, inp = _data([effect], HOUR, seed=23)
    result = diagnose(inp, config)
    assert "cross_coupling" in result.verdict["effects"], result.verdict["summary"]
    _assert_corrected(config, result.calibration, result.corrected)
    assert result.verdict["unexplained"], result.verdict["summary"]  # so the whole cross-talk of GRS1 is re-fitted
    refitted = {entry["variant"] for entry in result.corrected["refitted"]}
    assert {f"cross_coupling[grs1.{part}_{axis}]" for part in ("misalign", "imbalance") for axis in "xyz"} <= refitted


def test_a_diagonal_force_leakage_is_selected_term_by_term_and_corrects_d():
    """A force leakage of 0.0119 /m on each diagonal term from the start (1 h, seed 510001: a case of
    bench_corrected_calibration.py; the nominal d 15 sigma off along y on both GRS). Scored as rows, the z row
    was taken whole (its two empty terms absorbing part of the x term through the common d they alias), which
    filled three of the four effect slots: the x term was left out, the set read "unexplained" and the
    corrected d was 16 sigma off on the other side. Term by term the three diagonal terms are taken."""
    effect = {"name": "thruster_force_leakage", "leakage_per_m": (np.eye(3) * 0.0119).tolist()}
    config, inp = _data([effect], HOUR, seed=510001)
    result = diagnose(inp, config)
    assert result.verdict["effects"] == ["thruster_force_leakage"], result.verdict["summary"]
    assert {f"thruster_force_leakage[F{a}.T{a}]" for a in "xyz"} <= set(result.verdict["accepted_variants"])
    _assert_corrected(config, result.calibration, result.corrected)


def test_the_refit_beside_a_large_effect_runs_until_it_converges():
    """A force leakage of 0.0706 /m per diagonal term from 1,800 s (1 h, seed 510005; the nominal d 45 sigma off)
    re-fitted with a TM stiffness of GRS1 z from 1,791 s beside it, as the diagnosis named them: the
    instrumental-variable iteration contracts linearly (2.05, 1.64, 1.07, 0.63, ... sigma), and at the former limit
    of 8 iterations its last update was 0.1 sigma (in the diagnosis, from its named values, 0.84: withheld as not
    converged). It now runs on to below 0.05 sigma; the corrected G and d within 3 sigma of the truth."""
    effect = {"name": "thruster_force_leakage", "leakage_per_m": (np.eye(3) * 0.0706).tolist(), "onset_s": 1800.0}
    config, inp = _data([effect], HOUR, seed=510005)
    model = NominalModel.from_config(config)
    settings = record_settings(DiagnosisOptions())
    quiet = lambda message: None  # noqa: E731
    g, d, sigma_g, sigma_d = calibrate(inp, model, settings, 4, quiet)
    nominal = {"g_angular": g, "g_angular_sigma_relative": sigma_g, "com_offset_m": d, "com_offset_sigma_m": sigma_d}
    start = [{**effect, "leakage_per_m": (np.eye(3) * 1e-6).tolist()},
             {"name": "tm_stiffness", "stiffness_s2": 1e-9, "grs": 1, "axis": "z", "onset_s": 1791.0}]
    _, free = fixed_from_specs(start, model, settings)
    corrected = corrected_calibration(inp, model, settings, (0.0, 0.0, 0.0), [], nominal,
                                      float(0.5 * (inp.t_s[0] + inp.t_s[-1])), CORRECTED_ITERATIONS, quiet, free)
    assert corrected["last_update_sigma"] < 0.05, (corrected["last_update_sigma"], corrected["iterations"])
    assert not untrusted(corrected, CORRECTED_ITERATIONS)
    _assert_corrected(config, nominal, corrected)


# The corrected calibration alone, from a named value off by half the truth (a fitted magnitude as wrong as
# a partial model makes it): 30 min, seed 7, a few seconds each. (effect, named fraction, least nominal bias
# of G or d [sigma]). Readout family, measured nominal -> corrected worst G: imbalance 27.5 -> 1.4,
# misalignment 6.9 -> 1.9, drift 5.8 -> 1.9, nonlinearity 4.6 -> 1.9; held at the named value as before
# issue 39: 12.8, 3.6, 3.0, 11.0 (the nonlinearity's series form holds to k a_max ~ 0.2: k = 4e7 on phi
# already leaves 2.7 sigma re-fitted). Dynamics and test-mass families at magnitudes that bias G or d by
# 5-30 sigma over 30 min. The stiffness model is first order in k (diagnosis/correction.py): at 2e-4 s^-2
# its re-fitted value came out 5 % (12 sigma) high while G and d were corrected; 6e-5 keeps it within its
# sigma. The gravity gradient is left out: its physical value biases nothing (a scale of 30 is needed for
# 5 sigma in 1 h; there the attitude-free signature leaves G 4.5 sigma off).
_NAMED = [
    ({"name": "cross_coupling", "grs": 1, "imbalance": [1e-3, 0, 0]}, 0.5, 5.0),
    ({"name": "cross_coupling", "grs": 2, "misalignment_rad": [5e-3, 0, 0]}, 0.5, 5.0),
    ({"name": "scale_factor_drift", "rate_per_s": 3e-6, "grs": 1, "axis": "z", "t_ref_s": 0.0}, 0.5, 5.0),
    ({"name": "readout_nonlinearity", "k": 3e7, "grs": 1, "readout": "theta"}, 0.5, 4.0),
    ({"name": "thruster_torque_gain", "gain": 0.012, "axis": "y"}, 0.5, 5.0),
    ({"name": "inertia_error", "relative": [0.012, 0.0, 0.0]}, 0.5, 5.0),
    ({"name": "thruster_force_leakage", "leakage_per_m": (np.eye(3) * 1.3e-2).tolist()}, 0.5, 5.0),
    ({"name": "tm_stiffness", "stiffness_s2": 6e-5, "grs": 1, "axis": "x"}, 0.5, 5.0),
]


@pytest.mark.parametrize(("effect", "named_fraction", "g_min"), _NAMED,
                         ids=["imbalance", "misalignment", "scale_factor_drift", "readout_nonlinearity",
                              "thruster_torque_gain", "inertia_error", "thruster_force_leakage", "tm_stiffness"])
def test_corrected_calibration_refits_a_named_effect(effect, named_fraction, g_min):
    """The named value re-fitted with G and d: G and d back at the truth, the effect within 3 sigma of its truth."""
    config, inp = _data([effect], HOUR // 2, seed=7)
    model = NominalModel.from_config(config)
    settings = record_settings(DiagnosisOptions())
    t_mid = float(0.5 * (inp.t_s[0] + inp.t_s[-1]))
    quiet = lambda message: None  # noqa: E731
    g, d, sigma_g, sigma_d = calibrate(inp, model, settings, 4, quiet)
    nominal = {"g_angular": g, "g_angular_sigma_relative": sigma_g, "com_offset_m": d, "com_offset_sigma_m": sigma_d}
    named = dict(effect)
    for key in ("imbalance", "misalignment_rad", "rate_per_s", "k", "gain", "relative", "leakage_per_m", "scale",
                "stiffness_s2"):
        if key in named:
            named[key] = (named_fraction * np.asarray(named[key])).tolist()
    _, free = fixed_from_specs([named], model, settings)
    corrected = corrected_calibration(inp, model, settings, (0.0, 0.0, 0.0), [], nominal, t_mid, 4, quiet, free)
    _assert_corrected(config, nominal, corrected, g_min)
    _, truth = fixed_from_specs([effect], model, settings)
    for entry, (candidate, value, _, _) in zip(corrected["refitted"], truth, strict=True):
        assert entry["variant"] == candidate.key
        assert np.all(np.abs(np.asarray(entry["values"]) - value) < 3.0 * np.asarray(entry["sigmas"])), (entry, value)


def test_corrected_calibration_is_withheld_where_the_named_model_does_not_hold():
    """A readout nonlinearity of k = 1e8 from 900 s (k a_max ~ 0.1 beyond the range of its series form, where
    the diagnosis named it from its onset and the re-fit moved G ~85 sigma from the truth, the nominal being
    4-7 sigma off: bench_corrected_calibration.py): the re-fit says why it cannot be trusted, and the stage
    gives no corrected calibration (report: "Not given")."""
    effect = {"name": "readout_nonlinearity", "k": 1e8, "grs": 1, "readout": "phi", "onset_s": 900.0}
    config, inp = _data([effect], HOUR // 2, seed=7)
    model = NominalModel.from_config(config)
    settings = record_settings(DiagnosisOptions())
    quiet = lambda message: None  # noqa: E731
    g, d, sigma_g, sigma_d = calibrate(inp, model, settings, 4, quiet)
    nominal = {"g_angular": g, "g_angular_sigma_relative": sigma_g, "com_offset_m": d, "com_offset_sigma_m": sigma_d}
    _, free = fixed_from_specs([effect], model, settings)
    t_mid = float(0.5 * (inp.t_s[0] + inp.t_s[-1]))
    corrected = corrected_calibration(inp, model, settings, (0.0, 0.0, 0.0), [], nominal, t_mid,
                                      CORRECTED_ITERATIONS, quiet, free)
    assert untrusted(corrected, CORRECTED_ITERATIONS)
    # and a converged re-fit within the model's range is trusted
    assert not untrusted({"last_update_sigma": 0.01, "beyond_series_bound": []}, CORRECTED_ITERATIONS)


def test_a_quadratic_readout_refitted_with_g_is_not_shrunk_by_its_own_noise():
    """A readout nonlinearity of GRS2 psi (k = 2e7, 1 h, seeds 1-3; Type 1), re-fitted with G from its true
    value. Its series columns are powers of the measured psi acceleration, which carry the noise of the very
    channel they explain; built on them, the fit's normal equations shrank k (errors in variables) and G2 psi,
    which the quadratic term aliases with through the slow part of the psi acceleration (``2 k a0 a``), moved
    with it: k came out 2.42, 2.47 and 2.40 sigma low, G2 psi 2.2-2.4 sigma off where the nominal one was within
    0.9. The derivatives are now built on the noise-free accelerations (``Linearization.noise_free``, an
    instrument): k 1.02, 0.48, 0.67 sigma low, G2 psi 1.05, 0.48, 0.49 sigma off. Tolerance: the mean z of k over
    the three seeds within 3 sigma of that mean (sqrt(3) of one seed's), G and d of each within 3 sigma."""
    effect = {"name": "readout_nonlinearity", "k": 2e7, "grs": 2, "readout": "psi"}
    z_k = []
    for seed in (1, 2, 3):
        config, inp = _data([effect], HOUR, seed=seed)
        model = NominalModel.from_config(config)
        settings = record_settings(DiagnosisOptions())
        quiet = lambda message: None  # noqa: E731
        g, d, sigma_g, sigma_d = calibrate(inp, model, settings, 4, quiet)
        nominal = {"g_angular": g, "g_angular_sigma_relative": sigma_g, "com_offset_m": d,
                   "com_offset_sigma_m": sigma_d}
        _, free = fixed_from_specs([effect], model, settings)
        corrected = corrected_calibration(inp, model, settings, (0.0, 0.0, 0.0), [], nominal,
                                          float(0.5 * (inp.t_s[0] + inp.t_s[-1])), CORRECTED_ITERATIONS, quiet, free)
        assert not untrusted(corrected, CORRECTED_ITERATIONS), corrected["last_update_sigma"]
        corrected_g, corrected_d = _worst_z(config, corrected)
        assert corrected_g < 3.0 and corrected_d < 3.0, (seed, corrected_g, corrected_d)
        (refitted,) = corrected["refitted"]
        z_k.append((refitted["values"][0] - effect["k"]) / refitted["sigmas"][0])
    assert abs(np.mean(z_k)) < 3.0 / np.sqrt(len(z_k)), z_k
