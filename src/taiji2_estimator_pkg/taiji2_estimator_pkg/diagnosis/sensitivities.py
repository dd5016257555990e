"""Detection limits: the 1-sigma of every candidate variant's magnitude on given data."""

from __future__ import annotations

import numpy as np

from taiji2_estimator_pkg.diagnosis.candidates import candidate_catalog
from taiji2_estimator_pkg.diagnosis.inputs import DiagnosisInput
from taiji2_estimator_pkg.diagnosis.model import NominalModel
from taiji2_estimator_pkg.diagnosis.options import DiagnosisOptions, record_settings
from taiji2_estimator_pkg.diagnosis.record import Record, calibrate
from taiji2_model.config import SimConfig

__all__ = ["variant_sensitivities"]


def variant_sensitivities(inp: DiagnosisInput, nominal: NominalModel | SimConfig,
                          options: DiagnosisOptions | None = None) -> dict[str, float]:
    """1-sigma of every candidate variant's magnitude on these data, jointly with the nominal model.

    The detection limit of a variant is about ``sqrt(floor)`` sigma (the candidate gain floor,
    3.8 sigma for one parameter with the defaults). Used to set benchmark magnitudes.

    Parameters
    ----------
    inp : DiagnosisInput
        Data (typically clean).
    nominal : NominalModel or SimConfig
        Nominal model.
    options : DiagnosisOptions, optional
        Settings.

    Returns
    -------
    dict of str to float
        Variant key -> sigma of its magnitude (SI); for the star-tracker noise, sigma of f_knee^2.
    """
    options = options or DiagnosisOptions()
    model = nominal if isinstance(nominal, NominalModel) else NominalModel.from_config(nominal)
    settings = record_settings(options)
    g, d, _, _ = calibrate(inp, model, settings, max(2, options.calibration_iterations), lambda message: None)
    candidates, noise = candidate_catalog(options.candidates, options.orbit_period_s, options.suspension_hz,
                                          options.damping, options.st_corner_hz, model)
    t_mid = float(0.5 * (inp.t_s[0] + inp.t_s[-1]))
    record = Record(inp, model, g, d, settings, candidates, t_mid)
    out: dict[str, float] = {}
    for candidate in candidates:
        names = candidate.column_names()
        theta, cov, _ = record.fit(record.nuisance + names)
        zero = np.zeros(len(names))
        _, sigma = candidate.magnitude(zero, cov[-len(names):, -len(names):])
        out[candidate.key] = sigma
    if noise is not None:
        theta, _, _ = record.fit(record.nuisance)
        _, _, sigma_kappa = record.noise_gain(record.residual_fft(record.nuisance, theta))
        out[noise.key] = sigma_kappa
    return out
